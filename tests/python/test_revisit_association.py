"""benchmarks/revisit_association.py: several RJC draws a scene for D&C (--rjc-seeds), one run a
scene for the EKF, which draws nothing; the rows name their SlamConfig seed."""

import json
import math
import subprocess
import sys

from script_loader import ROOT, load_script

SCRIPT = ROOT / "benchmarks" / "revisit_association.py"


def test_config_seeds_give_dc_one_run_a_draw_and_the_ekf_one_run():
    module = load_script("benchmarks/revisit_association.py")
    assert module.config_seeds("dc", 3, 1) == [3]  # the default run: SlamConfig.seed = scene seed
    assert module.config_seeds("dc", 3, 3) == [3, 1003, 2003]
    assert module.config_seeds("ekf", 3, 3) == [3]


def test_overrides_are_read_and_unknown_fields_refused_by_name(capsys):
    module = load_script("benchmarks/revisit_association.py")
    assert module.parse_overrides(["local_map_features=20", "join_association=jcbb", "gate_confidence=0.999",
                                   "new_feature_margin=inf"]) == dict(
        local_map_features=20, join_association="jcbb", gate_confidence=0.999, new_feature_margin=math.inf)
    for item, says in (("local_map_feature=20", "did you mean local_map_features"),
                       ("local_map_features", "FIELD=VALUE"),
                       ("zzz=1", "'zzz' in 'zzz=1' is not a SlamConfig field")):
        try:
            module.parse_overrides([item])
        except SystemExit as refusal:
            assert refusal.code == 2  # a usage error, as argparse's
            assert says in capsys.readouterr().err
        else:
            raise AssertionError(f"{item!r} was accepted")


def test_rjc_draws_are_run_scored_and_listed(tmp_path):
    out = tmp_path / "runs.json"
    result = subprocess.run([sys.executable, str(SCRIPT), "--scenarios", "small_loop_laps", "--seeds", "1",
                             "--rjc-seeds", "2", "--json", str(out)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    runs = json.loads(out.read_text())["runs"]
    assert [(r["filter"], r["seed"], r["config_seed"]) for r in runs] == [("ekf", 0, 0), ("dc", 0, 0), ("dc", 0, 1000)]
    dc_recalls = [r["association"]["pairwise_recall"] for r in runs if r["filter"] == "dc"]
    row = next(line for line in result.stdout.splitlines() if line.split()[:2] == ["small_loop_laps", "dc"])
    # The D&C row is over both draws: its mean recall and its lowest.
    assert row.split()[3] == f"{sum(dc_recalls) / 2:.3f}"
    assert row.split()[-1] == f"{min(dc_recalls):.3f}"


def test_a_count_below_one_is_refused():
    result = subprocess.run([sys.executable, str(SCRIPT), "--rjc-seeds", "0"], capture_output=True, text=True)
    assert result.returncode != 0
    assert "--rjc-seeds must be at least 1" in result.stderr


def test_known_ids_run_with_the_simulators_ids():
    # association="known": the filters get the simulator's ids (clutter as -1), so the clustering
    # is the truth's and only the robot's error is left to score: the NEES ceiling.
    import dcslam

    module = load_script("benchmarks/revisit_association.py")
    sim = dcslam.revisit_scenario("small_loop_laps", 0)
    for filter_name in ("ekf", "dc"):
        config = dcslam.SlamConfig(association="known", join_association="known")
        scores, _ = module.run_one(filter_name, sim, config)
        assert scores.association.pairwise_precision == 1.0
        assert scores.association.pairwise_recall == 1.0
        assert scores.association.rejected == scores.association.clutter > 0
        assert scores.robot.position_error < 0.5
