"""The repository stands on its own: every reference to a documentation page in a tracked
text file names a file of the repository, and nothing points into a folder beside it.

A reference is a path ending in ``.md`` (a URL's tail is not one). It resolves when the file
exists relative to the repository's root, relative to the file that names it, or, for a bare
name, in ``docs/`` (prose says "docs/" once and then names its pages). A section sign after it
(``§4.5``, ``§4-§5``, ``§3 and §6``) must name a numbered heading of that page. Binary files
are skipped. The scan reads about 150 files and takes a few tens of milliseconds.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path
from typing import Iterable, List, Optional

import pytest

ROOT = Path(__file__).resolve().parents[2]

# Not preceded by a path or URL character, so that only whole paths match and the tail of a
# URL (another site's page) is left alone.
PAGE = re.compile(r"(?<![\w./:@-])((?:\.\.?/)*[\w-][\w.-]*(?:/[\w.-]+)*\.md)(?![\w-])")
SECTIONS = re.compile(r"(?:'s)?\s*(§\s*\d+(?:\.\d+)*(?:\s*(?:-|–|,|and|or|to)\s*§\s*\d+(?:\.\d+)*)*)")
SECTION_NUMBER = re.compile(r"§\s*(\d+(?:\.\d+)*)")
HEADING = re.compile(r"^#{1,6}\s+(\d+(?:\.\d+)*)\.?\s")
# A folder beside the repository (the lookahead keeps this file from matching itself).
OUTSIDE = re.compile(r"(?:\.\./)+shared\b|/work/(?=shared\b)")
PATH_TOKEN = re.compile(r"[^\s'\"`()<>,;]+")


def tracked_files(root: Path) -> List[Path]:
    try:
        listing = subprocess.run(["git", "-C", str(root), "ls-files", "-z"], capture_output=True,
                                 check=True, timeout=30).stdout
    except (OSError, subprocess.CalledProcessError) as error:
        pytest.skip(f"not a git checkout ({error})")
    return [root / name for name in listing.decode().split("\0") if name]


def text_of(path: Path) -> Optional[str]:
    """The file's text, or None for a binary (or vanished) file."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if b"\0" in data[:8192]:
        return None
    return data.decode("utf-8", errors="replace")


def headings(page: Path) -> set:
    numbers = set()
    for line in page.read_text(encoding="utf-8", errors="replace").splitlines():
        match = HEADING.match(line)
        if match:
            numbers.add(match.group(1))
    return numbers


def resolve(root: Path, referrer: Path, reference: str) -> Optional[Path]:
    root = root.resolve()
    places = [root / reference, referrer.parent / reference]
    if "/" not in reference:
        places.append(root / "docs" / reference)
    for place in places:
        place = place.resolve()
        if place.is_file() and (place == root or root in place.parents):
            return place
    return None


def broken_references(root: Path, files: Iterable[Path]) -> List[str]:
    """One line ``file:line: reference (why)`` per reference that does not resolve."""
    problems = []
    heading_cache = {}
    for path in files:
        text = text_of(path)
        if text is None:
            continue
        name = path.relative_to(root).as_posix()
        for number, line in enumerate(text.splitlines(), start=1):
            for match in OUTSIDE.finditer(line):
                token = PATH_TOKEN.match(line, match.start()).group(0)
                problems.append(f"{name}:{number}: {token} (outside the repository)")
            for match in PAGE.finditer(line):
                reference = match.group(1)
                target = resolve(root, path, reference)
                if target is None:
                    problems.append(f"{name}:{number}: {reference} (no such file in the repository)")
                    continue
                sections = SECTIONS.match(line, match.end())
                if not sections:
                    continue
                if target not in heading_cache:
                    heading_cache[target] = headings(target)
                for section in SECTION_NUMBER.findall(sections.group(1)):
                    if section not in heading_cache[target]:
                        problems.append(f"{name}:{number}: {reference} §{section} "
                                        f"(no heading numbered {section} in {target.relative_to(root.resolve()).as_posix()})")
    return problems


def test_every_documentation_reference_resolves_inside_the_repository():
    problems = broken_references(ROOT, tracked_files(ROOT))
    assert not problems, (f"{len(problems)} reference(s) do not resolve inside the repository:\n  "
                          + "\n  ".join(problems))


def test_the_scan_reports_what_does_not_resolve(tmp_path):
    # The names are assembled so that this file holds no broken reference itself.
    md = ".md"
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / f"page{md}").write_text("# Page\n\n## 2. Two\n\n### 2.1 Two one\n")
    (tmp_path / f"README{md}").write_text("top\n")
    (tmp_path / "src").mkdir()
    source = tmp_path / "src" / "code.hpp"
    source.write_text("\n".join([
        f"// docs/page{md} §2 and §2.1, page{md}, ../README{md}, README{md}",  # all resolve
        f"// docs/page{md} §3",                     # no such section
        f"// missing{md}; see https://example.org/missing{md}",  # the URL is not a reference
        "// data in ../" "shared/data and /work/" "shared/x",   # outside, twice
        f"// ../../elsewhere/page{md}",             # leaves the repository
    ]) + "\n")
    (tmp_path / "image.png").write_bytes(b"\x89PNG\0\0missing" + md.encode())

    problems = broken_references(tmp_path, [source, tmp_path / "image.png"])

    assert problems == [
        f"src/code.hpp:2: docs/page{md} §3 (no heading numbered 3 in docs/page{md})",
        f"src/code.hpp:3: missing{md} (no such file in the repository)",
        "src/code.hpp:4: ../" "shared/data (outside the repository)",
        "src/code.hpp:4: /work/" "shared/x (outside the repository)",
        f"src/code.hpp:5: ../../elsewhere/page{md} (no such file in the repository)",
    ]
