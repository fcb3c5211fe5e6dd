"""docs/models.md states every seed equation the code cites.

The seed papers are not in the repository, so a citation such as "seed 000 eq. 31" in a
docstring is only useful if docs/models.md states that equation. models.md marks each one
with "(seed NNN eq. N)". A citation names its seed ("seed 000 eq. 29-33", "seed 000's
eq. 22", "Seed 002 sec. I C, eq. 12") or is bare ("eq. 32"); a bare one refers to the seed
named last before it in the same file, or else to seed 000, the main system (the rule
models.md gives its readers). Ranges ("eq. 29-33") and lists ("eq. 28 and 32", "eq. 1-3, 11")
cite every number in them.
"""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MODELS_MD = REPO / "docs" / "models.md"
SOURCES = ("ekf_localization", "sim_robot", "seed_experiments", "benchmarks", "config", "test")
MAIN_SEED = "000"

_NUMBER = r"\d+(?![.\d])"
_SPAN = rf"{_NUMBER}(?:\s*[-–]\s*{_NUMBER})?"
# an optional named seed right before "eq.": "seed 000 ", "seed 000's ", "seed 000, ",
# "seed 000 (", "seed 002 sec. I C, "
CITATION = re.compile(
    rf"(?:\bseed\s+(?P<seed>\d{{3}})(?:'s)?(?:,|\s\(|\s+sec\.[^,\n]{{0,12}},)?\s+)?"
    rf"\beq\.\s*(?P<numbers>{_SPAN}(?:\s*(?:,|and)\s*{_SPAN})*)", re.IGNORECASE)
SEED_NAME = re.compile(r"\bseed\s+(\d{3})", re.IGNORECASE)
MARKER = re.compile(r"\(seed (\d{3}) eq\. (\d+)\)")


def numbers(text: str) -> list[int]:
    """Every equation number in "29-33", "28 and 32", "1-3, 11"."""
    out: list[int] = []
    for span in re.split(r"\s*(?:,|and)\s*", text.strip()):
        ends = [int(n) for n in re.split(r"\s*[-–]\s*", span)]
        out.extend(range(ends[0], ends[-1] + 1))
    return out


def citations(text: str) -> list[tuple[int, str | None, str | None, int]]:
    """(line, named seed or None, seed named last before it or None, number) per cited equation."""
    named = [(m.start(), m.group(1)) for m in SEED_NAME.finditer(text)]
    out = []
    for m in CITATION.finditer(text):
        before = [seed for pos, seed in named if pos < m.start()]
        line = text.count("\n", 0, m.start()) + 1
        out.extend((line, m.group("seed"), before[-1] if before else None, n)
                   for n in numbers(m.group("numbers")))
    return out


def stated() -> set[tuple[str, int]]:
    return {(seed, int(n)) for seed, n in MARKER.findall(MODELS_MD.read_text(encoding="utf-8"))}


def _source_files() -> list[Path]:
    files = []
    for root in SOURCES:
        for pattern in ("*.py", "*.yaml"):
            files.extend(p for p in (REPO / root).rglob(pattern) if p.resolve() != Path(__file__).resolve())
    return sorted(files)


def test_the_citation_reader_reads_ranges_lists_and_named_seeds() -> None:
    text = ("Seed 001 eq. 3 row 4; the seed 000's eq. 22 and 25;\n"
            "eq. 29-31, 33 (seed 002 sec. I C, eq. 12) eq. 26, 0.45 (seed 000, eq. 34-35)")
    assert citations(text) == [
        (1, "001", None, 3), (1, "000", "001", 22), (1, "000", "001", 25),
        (2, None, "000", 29), (2, None, "000", 30), (2, None, "000", 31), (2, None, "000", 33),
        (2, "002", "000", 12), (2, None, "002", 26), (2, "000", "002", 34), (2, "000", "002", 35)]
    assert numbers("1-3, 11") == [1, 2, 3, 11]
    assert MARKER.findall("x (seed 000 eq. 31): y") == [("000", "31")]


def test_models_md_states_every_cited_equation() -> None:
    docs = stated()
    missing = []
    count = 0
    for path in _source_files():
        for line, seed, last_named, n in citations(path.read_text(encoding="utf-8")):
            count += 1
            where = f"{path.relative_to(REPO)}:{line}"
            if seed is not None:
                if (seed, n) not in docs:
                    missing.append(f"{where}: seed {seed} eq. {n}")
            elif not {(last_named or MAIN_SEED, n), (MAIN_SEED, n)} & docs:
                seeds = " or ".join(dict.fromkeys((last_named or MAIN_SEED, MAIN_SEED)))
                missing.append(f"{where}: eq. {n} (seed {seeds})")
    assert count > 100, "the reader found too few citations: has the citation form changed?"
    assert not missing, "docs/models.md does not state:\n" + "\n".join(missing)


def test_models_md_states_each_equation_once() -> None:
    markers = MARKER.findall(MODELS_MD.read_text(encoding="utf-8"))
    repeated = sorted({m for m in markers if markers.count(m) > 1})
    assert not repeated, f"stated more than once: {repeated}"
