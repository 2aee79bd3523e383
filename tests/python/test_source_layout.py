"""The C++ sources' folders depend one way (docs/design.md §1): core <- association <-
estimation <- joining, and datasets on core only. Every ``#include "dcslam/<folder>/..."`` of
a header or source in a folder must name that folder or one below it, and name a file that
exists; and no component (a header with its source) reaches itself through includes."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BELOW = {
    "core": {"core"},
    "association": {"core", "association"},
    "estimation": {"core", "association", "estimation"},
    "joining": {"core", "association", "estimation", "joining"},
    "datasets": {"core", "datasets"},
}
INCLUDE = re.compile(r'^\s*#\s*include\s+"dcslam/([^"]+)"', re.MULTILINE)


def sources():
    for base in (ROOT / "include" / "dcslam", ROOT / "cpp"):
        for path in sorted(base.rglob("*.[ch]pp")):
            yield path, path.relative_to(base).parts[0]


def test_every_source_is_in_a_known_folder():
    misplaced = [str(path.relative_to(ROOT)) for path, folder in sources() if folder not in BELOW]
    assert not misplaced


@pytest.mark.parametrize("folder", sorted(BELOW))
def test_includes_run_one_way(folder):
    wrong = []
    for path, where in sources():
        if where != folder:
            continue
        for included in INCLUDE.findall(path.read_text(encoding="utf-8")):
            target = included.split("/")[0]
            if target not in BELOW[folder] or not (ROOT / "include" / "dcslam" / included).is_file():
                wrong.append(f"{path.relative_to(ROOT)}: dcslam/{included}")
    assert not wrong



def test_no_include_cycle():
    """A header and its source are one component: a source that includes a header including
    the source's own header closes a cycle as surely as two headers including each other."""
    graph = {}
    for base in (ROOT / "include" / "dcslam", ROOT / "cpp"):
        for path in sorted(base.rglob("*.[ch]pp")):
            component = path.relative_to(base).with_suffix("").as_posix()
            reached = {Path(included).with_suffix("").as_posix()
                       for included in INCLUDE.findall(path.read_text(encoding="utf-8"))}
            graph.setdefault(component, set()).update(reached - {component})
    cycles = []
    open_path = []
    finished = set()

    def visit(component):
        open_path.append(component)
        for reached in sorted(graph.get(component, ())):
            if reached in open_path:
                cycles.append(" -> ".join(open_path[open_path.index(reached):] + [reached]))
            elif reached not in finished:
                visit(reached)
        open_path.pop()
        finished.add(component)

    for component in sorted(graph):
        if component not in finished:
            visit(component)
    assert not cycles
