"""The bench's results: rows of figure, reference, ratio and goal, per section; printed as
Markdown tables (to paste into docs/benchmark.md) or as one JSON object.

A row's `met` is None where no goal is set, or where nothing could be measured (a host that is
not installed, a flag the emulator does not have yet): absent is not failed.
"""

from dataclasses import dataclass, field

MET, MISSED = "✓", "✗"


@dataclass
class Row:
    figure: str
    measured: str
    reference: str = "—"
    ratio: float | None = None
    goal: str = "—"
    met: bool | None = None
    data: dict = field(default_factory=dict)  # the raw numbers, for --json

    def as_dict(self) -> dict:
        return {"figure": self.figure, "measured": self.measured, "reference": self.reference,
                "ratio": self.ratio, "goal": self.goal, "met": self.met, **self.data}


@dataclass
class Table:
    """A matrix of figures beside a section's rows (the protocol lab's variants by condition)."""

    title: str
    header: tuple[str, ...]
    rows: list[tuple[str, ...]] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"title": self.title, "header": list(self.header),
                "rows": [list(row) for row in self.rows]}


@dataclass
class Section:
    key: str  # the --only name
    title: str
    columns: tuple[str, str, str]  # headers: the figure, what was measured, the reference
    rows: list[Row] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0  # how long the section took, for whoever wonders where time went
    tables: list[Table] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"title": self.title, "rows": [row.as_dict() for row in self.rows],
                "notes": self.notes, "seconds": round(self.seconds, 1),
                **({"tables": [table.as_dict() for table in self.tables]} if self.tables else {})}


def ratio_text(ratio: float | None) -> str:
    if ratio is None:
        return "—"
    return f"{ratio:.2f}" if ratio < 10 else f"{ratio:,.0f}"


def met_text(met: bool | None) -> str:
    return "" if met is None else MET if met else MISSED


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def markdown(sections: list[Section], preamble: list[str]) -> str:
    out = list(preamble)
    for section in sections:
        out += ["", f"### {section.title}", ""]
        header = [*section.columns, "ratio", "goal", "met"]
        out.append("| " + " | ".join(header) + " |")
        out.append("| --- | ---: | ---: | ---: | --- | :-: |")
        for row in section.rows:
            cells = [row.figure, row.measured, row.reference, ratio_text(row.ratio), row.goal,
                     met_text(row.met)]
            out.append("| " + " | ".join(_cell(cell) for cell in cells) + " |")
        if section.notes:
            out.append("")
            out += [f"- {note}" for note in section.notes]
        for table in section.tables:
            out += ["", f"#### {table.title}", ""]
            out.append("| " + " | ".join(table.header) + " |")
            out.append("| --- |" + " ---: |" * (len(table.header) - 1))
            out += ["| " + " | ".join(_cell(cell) for cell in row) + " |" for row in table.rows]
    goals = [row.met for section in sections for row in section.rows if row.met is not None]
    out += ["", f"Goals: {goals.count(True)} met, {goals.count(False)} missed."]
    return "\n".join(out)


def as_json(sections: list[Section], meta: dict) -> dict:
    goals = [row.met for section in sections for row in section.rows if row.met is not None]
    return {**meta, "goals": {"met": goals.count(True), "missed": goals.count(False)},
            "sections": {section.key: section.as_dict() for section in sections}}


def rate(value: float | None, unit: str = "cmd/s") -> str:
    return "—" if value is None else f"{value:,.0f} {unit}" if value >= 100 else \
        f"{value:,.1f} {unit}"
