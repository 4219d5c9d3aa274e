"""Every figure the README's headline quotes stands in a table of docs/results.md.

The README's headline is its "**Which to use when.**" paragraph and the table under it (the README's statement of
what ships and how each checkpoint and the per-object replay score on the test splits): the text from that bold
phrase to the first blank line after the table. Its figures are successes over episodes (``315/360``), percentages
(``87.5%``) and signed point differences (``+13.1``, ``−28.9``); each must appear, as a whole figure, in a row of a
markdown table of docs/results.md (a line that starts with ``|``), so that the README cannot quote a figure that
results.md's tables of what ships do not hold. Pure text: no evaluation is run.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
RESULTS = ROOT / "docs" / "results.md"
HEADLINE_START = "**Which to use when.**"

MINUS = "\u2212"
COUNT = r"(?:\d{1,3}(?:,\d{3})+|\d+)"  # 360 or 1,092,000
# a figure: successes/episodes, a percentage, or a signed number; never part of a longer number
FIGURE = re.compile(rf"(?<![\w.,/+\u2212])(?:{COUNT}/{COUNT}|\d+(?:\.\d+)?%|[+\u2212]\d+(?:\.\d+)?)(?!\w|[.,/]\d|/)")


def figures(text: str) -> list[str]:
    """The figures of ``text`` in order, an ASCII hyphen before a digit read as a minus sign."""
    return FIGURE.findall(re.sub(r"(?<![\w-])-(?=\d)", MINUS, text))


def headline(readme: str) -> str:
    """The README's headline: from "**Which to use when.**" to the first blank line after the table under it."""
    start = readme.index(HEADLINE_START)
    lines = readme[start:].split("\n")
    end = next(i for i, line in enumerate(lines) if line.startswith("|"))
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    return "\n".join(lines[:end])


def table_rows(markdown: str) -> list[str]:
    return [line for line in markdown.split("\n") if line.startswith("|")]


def test_the_extractor_reads_every_kind_of_figure():
    text = ("**315/360**, 178/300: 87.5% (+13.1 points, -2.8 to −1.0), +1.3, 24/30; 1,092,000/2,000; "
            "MT10, step-93,000, 2026-11-28, 0.662×, (27–66), 10^6")
    assert figures(text) == ["315/360", "178/300", "87.5%", "+13.1", "−2.8", "−1.0", "+1.3", "24/30",
                             "1,092,000/2,000"]


def test_every_figure_of_the_readme_headline_is_in_a_results_table():
    quoted = figures(headline(README.read_text()))
    assert len(quoted) >= 6, f"the README's headline quotes too few figures to check: {quoted}"
    in_tables = {figure for row in table_rows(RESULTS.read_text()) for figure in figures(row)}
    missing = [figure for figure in quoted if figure not in in_tables]
    assert not missing, f"figures the README's headline quotes that no table of docs/results.md holds: {missing}"
