"""The README's speed figures are the benchmarks': each number of its speed table's ratio column is
written in a block of benchmarks/RESULTS.md that names the row's peer (the first quoted or
capitalised name of its "against" column), those marked AVX2 in such a block measured on an AVX2
machine, and a "faster" factor is the inverse of a ratio quoted beside it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NUMBER = r"\d+(?:\.\d+)?"


def _rows():
    text = (ROOT / "README.md").read_text()
    table = text[text.index("## Speed"):text.index("## Documentation")]
    rows = [line for line in table.splitlines() if line.startswith("| ") and not line.startswith("| operation")]
    return [[cell.strip() for cell in row.strip("|").split("|")] for row in rows]


def _blocks():
    text = (ROOT / "benchmarks" / "RESULTS.md").read_text()
    return re.findall(r"<!-- BEGIN \S+ -->(.*?)<!-- END \S+ -->", text, re.S)


def _tokens(text: str) -> set[str]:
    return set(re.findall(rf"(?<![\w.]){NUMBER}(?![\w.]\d)", text))


ROWS = _rows()


def test_the_table_is_read():
    assert len(ROWS) >= 6 and all(len(row) == 3 for row in ROWS)


@pytest.mark.parametrize("row", ROWS, ids=[row[0][:40] for row in ROWS])
def test_each_ratio_is_in_the_results(row):
    cell = row[2]
    faster = re.search(rf"\(({NUMBER})-({NUMBER})x faster\)", cell)
    quoted = re.sub(r"\([^)]*faster\)", "", cell)
    avx2 = re.search(r"\(AVX2(?:: ([^)]*))?\)", quoted)
    if avx2 and avx2.group(1):          # "x (AVX2: y)": x from the AVX-512 blocks, y from an AVX2 one
        plain, on_avx2 = quoted[:avx2.start()], avx2.group(1)
    elif avx2:                          # "x (AVX2)": x itself measured on AVX2
        plain, on_avx2 = "", quoted[:avx2.start()]
    else:
        plain, on_avx2 = quoted, ""
    peer = (re.findall(r"`([^`]+)`", row[1])
            + [w for w in re.findall(r"[A-Za-z][\w.-]*", row[1]) if w[0].isupper() or "-" in w])[0]
    blocks = [block for block in _blocks() if peer in block]
    assert blocks, f"{row[0]}: no block of benchmarks/RESULTS.md names {peer!r}"
    everywhere = set().union(*(_tokens(block) for block in blocks))
    on_avx2_blocks = set().union(*(_tokens(block) for block in blocks if "AVX2" in block))
    for number in re.findall(NUMBER, plain):
        assert number in everywhere, f"{row[0]}: {number} is not in a block of benchmarks/RESULTS.md naming {peer!r}"
    for number in re.findall(NUMBER, on_avx2):
        assert number in on_avx2_blocks, f"{row[0]}: {number} is not in an AVX2 block naming {peer!r}"
    if faster:
        ratios = [float(n) for n in re.findall(NUMBER, plain)]
        assert round(1 / max(ratios)) == int(faster.group(1)) and round(1 / min(ratios)) == int(faster.group(2))


#: Figures of the guides that are derived from RESULTS.md rather than quoted: figure -> the numbers
#: it is derived from (each must be in RESULTS.md) and how.
DERIVED = {
    "5-300x": (("0.18", "3e-03"), "the inverses of true / estimate on the tiny light's glint (estimator block)"),
}


def _guide_pages():
    docs = ROOT / "docs"
    return sorted((docs / "guides").glob("*.md")) + [docs / "robustness.md"]


@pytest.mark.parametrize("page", _guide_pages(), ids=lambda p: p.name)
def test_the_guides_ratios_are_in_the_results(page):
    """Every ratio a guide's prose quotes (``0.47x``, ``2-4.6x``) is a number of benchmarks/RESULTS.md,
    or derived from some (:data:`DERIVED`, which names them)."""
    results = "".join(_blocks())
    written = _tokens(results)
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    for match in re.finditer(rf"(?<![\w.])({NUMBER})(?:-({NUMBER}))?x(?!\w)", text):
        if match.group(0) in DERIVED:
            sources, _ = DERIVED[match.group(0)]
            assert all(source in results for source in sources), match.group(0)
            continue
        for number in filter(None, match.groups()):
            assert number in written, f"{page.name}: {match.group(0)} is not in benchmarks/RESULTS.md"
