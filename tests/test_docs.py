"""The documentation holds together: every relative link in the Markdown a reader starts from
resolves (the file exists and, where the link names an anchor, the file has that heading), and
the README stays a five-minute read that gives the two commands of a fresh machine."""

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parent.parent
README_LIMIT = 10 * 1024  # bytes

INSTALL_AND_RUN = (
    "python3 -m venv .venv && .venv/bin/pip install . && .venv/bin/fake-marlin --link /tmp/printer"
)
INSTALL_AND_TEST = (
    "python3 -m venv .venv && .venv/bin/pip install -e '.[test]' && "
    ".venv/bin/python -m tests.hosts.install && .venv/bin/python -m pytest"
)


def documents() -> list[Path]:
    found = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md"))]
    found += [ROOT / "scenarios" / "README.md", ROOT / "fuzz" / "README.md"]
    return found


FENCE = re.compile(r"^ {0,3}(```|~~~)")
HEADING = re.compile(r"^ {0,3}(#{1,6})[ \t]+(.*?)(?:[ \t]+#+)?[ \t]*$")
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")
INLINE_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]*)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE = re.compile(r"^ {0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+\"[^\"]*\")?\s*$")


def prose_lines(text: str) -> list[str]:
    """The lines of a Markdown text outside code blocks (fenced, or indented after a blank
    line), with code spans blanked out: what a renderer reads links and headings from."""
    lines = []
    fence = None
    previous_blank, in_indented = True, False
    for line in text.splitlines():
        opening = FENCE.match(line)
        if fence is not None:
            if opening and opening.group(1) == fence:
                fence = None
            continue
        if opening:
            fence = opening.group(1)
            continue
        indented = line.startswith(("    ", "\t")) and bool(line.strip())
        if indented and (previous_blank or in_indented):
            in_indented = True
            continue
        in_indented = in_indented and not line.strip()
        previous_blank = not line.strip()
        lines.append(CODE_SPAN.sub("", line))
    return lines


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: its text (links and emphasis read as their words),
    lowercase, every character but letters, digits, `-`, `_` and spaces removed, each space a
    `-`."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)
    text = re.sub(r"<[^>]+>", "", text).lower()
    text = "".join(c for c in text if c.isalnum() or c in "-_ ")
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    found = set()
    fence = None
    for line in path.read_text(encoding="utf-8").splitlines():
        opening = FENCE.match(line)
        if fence is not None:
            fence = None if opening and opening.group(1) == fence else fence
            continue
        if opening:
            fence = opening.group(1)
            continue
        heading = HEADING.match(line)
        if not heading:
            continue
        base = slug(heading.group(2).replace("`", ""))
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(base if count == 0 else f"{base}-{count}")
    return found


def links(path: Path) -> list[str]:
    found = []
    for line in prose_lines(path.read_text(encoding="utf-8")):
        found += INLINE_LINK.findall(line)
        reference = REFERENCE.match(line)
        if reference:
            found.append(reference.group(1))
    return found


def broken_links(path: Path) -> list[str]:
    problems = []
    for target in links(path):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):  # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition("#")
        linked = (path.parent / unquote(file_part)).resolve() if file_part else path
        if not linked.exists():
            problems.append(f"{target}: no such file")
        elif anchor and linked.suffix == ".md" and unquote(anchor) not in anchors(linked):
            problems.append(f"{target}: {linked.name} has no heading #{anchor}")
    return problems


@pytest.mark.parametrize("path", documents(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(path: Path) -> None:
    assert path.exists()
    problems = broken_links(path)
    assert not problems, f"{path.relative_to(ROOT)}:\n" + "\n".join(problems)


def test_the_readme_is_a_five_minute_read() -> None:
    size = (ROOT / "README.md").stat().st_size
    assert size <= README_LIMIT, f"README.md is {size} bytes; move reference material to docs/"


def test_the_readme_gives_the_two_commands_of_a_fresh_machine() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert INSTALL_AND_RUN in text
    assert INSTALL_AND_TEST in text


def test_docs_readme_indexes_every_doc() -> None:
    index = links(ROOT / "docs" / "README.md")
    names = {p.name for p in (ROOT / "docs").glob("*.md")} - {"README.md"}
    assert names <= {target.partition("#")[0] for target in index}


@pytest.mark.parametrize(
    "heading, anchor",
    [
        ("The printer: `fake-marlin`", "the-printer-fake-marlin"),
        ("Marlin ASCII (`--protocol marlin`)", "marlin-ascii---protocol-marlin"),
        ("1. Ultimaker UM3/S5 protocol", "1-ultimaker-um3s5-protocol"),
        ("Farms: 200 printers idle, 50 streaming", "farms-200-printers-idle-50-streaming"),
        ("See [the trace](trace.md) *now*", "see-the-trace-now"),
        ("Ümlaut_and dash-es", "ümlaut_and-dash-es"),
    ],
)
def test_anchors_are_githubs(heading: str, anchor: str) -> None:
    assert slug(heading) == anchor


def test_a_broken_link_is_found(tmp_path: Path) -> None:
    (tmp_path / "other.md").write_text("# Other\n\n## Same\n\n## Same\n", encoding="utf-8")
    doc = tmp_path / "doc.md"
    doc.write_text(
        "# Doc\n\n[ok](other.md#same-1) [ok](#doc) [ok](https://example.com/x.md)\n"
        "`[not a link](gone.md)`\n\n    [code](gone.md)\n\n```\n[code](gone.md)\n```\n"
        "[bad](missing.md) [bad](other.md#same-2) [bad](#nowhere)\n",
        encoding="utf-8",
    )
    assert [problem.split(":")[0] for problem in broken_links(doc)] == [
        "missing.md",
        "other.md#same-2",
        "#nowhere",
    ]
