"""Did the printer run a job exactly once, in order? The job's commands against a journal.

The journal is aligned with the job as two sequences, never compared as sets: jobs repeat
commands (`G92 E0` every layer, identical moves), and only an alignment can say which of the
repeats was lost or run twice. The alignment is a longest common subsequence, by Myers' diff
algorithm (GNU diff's and git's). `difflib.SequenceMatcher` was the first candidate, but it
grows matches from the longest contiguous block, which with repeated lines is no shortest edit:
for the job `A B A A` run as `A A A` it reports line 1 reordered and line 2 missing instead of
line 2 missing; and it is quadratic in how often lines repeat.

Myers' time grows with the number of differences D (about D² steps), not with the length, and
journal lines that are no job command at all (host polls, garbage) never enter the alignment,
so D counts only real problems. Up to MAX_EDITS of them the alignment is exact. Beyond, lines
that occur exactly once on both sides (most moves: their coordinates make them unique) are
matched first, as anchors, as git's patience diff does, and each stretch between anchors is
aligned exactly on its own; a stretch with more than MAX_EDITS differences (a journal of another
job) is not aligned at all, its commands only paired by text, and the result says it is
approximate.

A job command that is missing where a journal line ran in its place that differs from it in a
few characters, or is it cut short, ran damaged: the wire changed it in a way the protocol's
check could not see (Marlin's XOR checksum misses two flips of the same bit, in the line or in
its checksum digits). It is
reported as such, apart from missing and duplicated commands; the printer did what the real
firmware does, and no host can prevent it, so a caller may accept it (allow_undetectable).

Pure: no I/O. `fake_marlin.emulator.cli.verify` reads the files and prints the report.
"""

import bisect
import re
from collections import Counter, defaultdict, deque
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

from fake_marlin.wire.gcode import canonical, strip_comment

HOST_COMMANDS = frozenset({"M105", "M110", "M113", "M114", "M115", "M155", "M27", "M400"})
"""Commands hosts send on their own: OctoPrint's `M110 N0`, `M115`, `M113 S2`, `M105` polls and
final `M400`, printcore's `M110 N-1`. They only report or synchronise, so one the alignment
cannot place is counted as the host's (an extra), even when the job has the same command."""

MAX_EDITS = 1000
"""Differences (missing and extra runs) one alignment may find before it gives up. Myers' time
is about their square, and their number times the length when few lines are unique: 1000 in a
100,000-line job of nothing but two alternating lines (the worst case) take about 3 s."""

DAMAGED_AT_MOST = 4
"""Characters that may differ between a job command and what ran in its place for it to count
as that command damaged, rather than a command lost and another one run."""

_COMMAND_WORD = re.compile(r"[A-Za-z]\d+")


class Kind(Enum):
    MISSING = "missing"  # a job command that never ran
    DUPLICATED = "duplicated"  # a job command that ran again
    REORDERED = "reordered"  # a job command that ran, but not in its place
    EXTRA = "extra"  # a journal line that is not the job's: the host's own command, or garbage
    DAMAGED = "ran damaged"  # a job command that ran changed, past the protocol's check


FAILURES = (Kind.MISSING, Kind.DUPLICATED, Kind.REORDERED, Kind.DAMAGED)


@dataclass(frozen=True)
class Problem:
    kind: Kind
    command: str
    job_line: int | None  # None for an extra
    journal_line: int | None  # where it ran; None for a missing command
    ran_as: str | None = None  # what a damaged command ran as


@dataclass(frozen=True)
class Verification:
    problems: tuple[Problem, ...]  # in journal order; a missing command where it was due
    job_commands: int
    journal_commands: int
    approximate: bool = False  # some stretch was too different to align exactly

    def count(self, kind: Kind) -> int:
        return sum(problem.kind is kind for problem in self.problems)

    def failures(self, strict: bool = False, allow_undetectable: bool = False) -> tuple[Problem, ...]:
        """Extras are the host's business unless `strict`; damage the protocol cannot see is
        no failure with `allow_undetectable`."""
        return tuple(
            p for p in self.problems
            if (strict or p.kind in FAILURES) and not (allow_undetectable and p.kind is Kind.DAMAGED)
        )

    def passed(self, strict: bool = False, allow_undetectable: bool = False) -> bool:
        return not self.failures(strict, allow_undetectable)


def job_commands(text: str) -> list[tuple[int, str]]:
    """(line number, command) for each command, numbered as `fake-marlin-host` numbers them."""
    return [(number, command) for number, line in enumerate(text.splitlines(), 1)
            if (command := strip_comment(line))]


def is_host_command(command: str) -> bool:
    word = _COMMAND_WORD.match(command)
    return word is not None and word.group().upper() in HOST_COMMANDS


def verify(job: Sequence[tuple[int, str]], journal: Sequence[str]) -> Verification:
    """Explain the journal as the job run once in order, plus as few problems as possible.

    `job` holds (line number, command) pairs; `journal[k]` is journal line k + 1 (blank lines are
    no commands). A journal line that is no job command is an extra. One that is runs a job
    command: in its place if the alignment matches it, else one that was not run in its place
    (reordered), else one that already ran (duplicated); host commands are extras instead, since
    hosts send them on their own. A job command run nowhere is missing.
    """
    # Commands are compared in one spelling (wire.gcode.canonical): a binary protocol brings
    # `G1 X10 F3000` to the printer for the job's `G1 F3000 X10.0`. Problems quote the job.
    written = {number: line.strip() for number, line in enumerate(journal, 1)}
    # Each text is spelled once (its numbers' shortest float32 forms are what cost): a journal
    # mostly repeats its job's lines, and a job repeats its own.
    spelling = {text: canonical(text)
                for text in {command for _, command in job} | set(written.values())}
    texts = [spelling[command] for _, command in job]
    in_job = set(texts)
    ran = [(number, spelling[line]) for number, line in written.items() if line]
    runs = [(number, command) for number, command in ran if command in in_job]
    found: list[tuple[tuple[float, int], Problem]] = [  # ((journal position, job index), problem)
        ((number, -1), Problem(Kind.EXTRA, written[number], None, number))
        for number, command in ran if command not in in_job
    ]
    pairs, approximate = _align(texts, [command for _, command in runs])

    ran_at: list[int | None] = [None] * len(texts)  # journal line that ran job command i
    in_place = [False] * len(runs)
    for i, k in pairs:
        ran_at[i] = runs[k][0]
        in_place[k] = True
    due_after = {}  # job index not run in place -> journal line after which it was due
    waiting: defaultdict[str, deque[int]] = defaultdict(deque)  # command -> those job indices, in job order
    last = 0
    for i, command in enumerate(texts):
        at = ran_at[i]
        if at is None:
            due_after[i] = last
            if not is_host_command(command):
                waiting[command].append(i)
        else:
            last = at

    again = []
    for k, (number, command) in enumerate(runs):
        if in_place[k]:
            continue
        if is_host_command(command):
            found.append(((number, -1), Problem(Kind.EXTRA, written[number], None, number)))
        elif waiting[command]:
            i = waiting[command].popleft()
            ran_at[i] = number
            found.append(((number, i), Problem(Kind.REORDERED, job[i][1], job[i][0], number)))
        else:
            again.append((number, command))
    unrun = [i for i in due_after if ran_at[i] is None]
    found, again, damaged = _damaged(unrun, found, again, job, written, ran_at, due_after)
    for i in unrun:
        if i not in damaged:
            missing = Problem(Kind.MISSING, job[i][1], job[i][0], None)
            found.append(((due_after[i] + 0.5, i), missing))

    # A repeat is charged to the run of the same command just before it. With none before, it
    # ran first, and the first run after it counts as the repeat instead.
    history = defaultdict(list)  # command -> sorted (journal line, job index) of its runs
    for i, at in enumerate(ran_at):
        if at is not None:
            history[texts[i]].append((at, i))
    for done in history.values():
        done.sort()
    for number, command in again:
        done = history[command]
        before = bisect.bisect_left(done, (number,))
        if before:
            i = done[before - 1][1]
        else:
            first, i = done[0]
            done[0] = (number, i)
            number = first
        found.append(((number, i), Problem(Kind.DUPLICATED, job[i][1], job[i][0], number)))

    found.sort(key=lambda entry: entry[0])
    return Verification(
        problems=tuple(problem for _, problem in found),
        job_commands=len(texts),
        journal_commands=len(ran),
        approximate=approximate,
    )


def _damaged(
    unrun: list[int],
    found: list[tuple[tuple[float, int], Problem]],
    again: list[tuple[int, str]],
    job: Sequence[tuple[int, str]],
    written: dict[int, str],
    ran_at: list[int | None],
    due_after: dict[int, int],
) -> tuple[list[tuple[tuple[float, int], Problem]], list[tuple[int, str]], set[int]]:
    """Job commands that did not run, each of which a damaged copy ran in place of: where it
    was due, a journal line of its length that differs in a few characters (an extra, or what
    would look like a repeat of another command). Returns `found` with those extras replaced by
    the damaged commands, `again` without those lines, and the job indices they stand for."""
    if not unrun:
        return found, again, set()
    next_ran, upcoming = [0.0] * len(job), float("inf")  # journal line of the next command run
    for i in range(len(job) - 1, -1, -1):
        next_ran[i] = upcoming
        at = ran_at[i]
        if at is not None:
            upcoming = at
    candidates = sorted(
        [p.journal_line for _, p in found if p.kind is Kind.EXTRA and p.journal_line is not None]
        + [number for number, _ in again]
    )
    used: dict[int, int] = {}  # journal line -> the job index it ran damaged for
    for i in unrun:
        expected = job[i][1].strip()
        window = candidates[bisect.bisect_right(candidates, due_after[i]):]
        match = next(
            (n for n in window if n < next_ran[i] and n not in used
             and _looks_damaged(expected, written[n])),
            None,
        )
        if match is not None:
            used[match] = i
    kept = [
        (key, problem) for key, problem in found
        if not (problem.kind is Kind.EXTRA and problem.journal_line in used)
    ]
    kept += [
        ((n, i), Problem(Kind.DAMAGED, job[i][1], job[i][0], n, ran_as=written[n]))
        for n, i in used.items()
    ]
    return kept, [(n, command) for n, command in again if n not in used], set(used.values())


def describe_damage(problem: Problem) -> str:
    return (f"ran damaged: job line {problem.job_line} `{problem.command}` ran as "
            f"`{problem.ran_as}` (its checksum cannot see this)")


def _looks_damaged(expected: str, ran: str) -> bool:
    """Could `ran` be `expected` changed on the wire? A few characters changed (an edit
    distance of at most DAMAGED_AT_MOST, and a quarter of its length: a flipped space after
    the line number leaves a character in front), or cut short after its first parameter: the
    flips that pass Marlin's XOR checksum (two of one bit) can make a `*` of a `.`, and the
    firmware then runs the line only up to it."""
    if ran == expected:
        return False
    # A short command is another command after a few changes: G1 X3 is four from G92 E0.
    limit = min(DAMAGED_AT_MOST, len(expected) // 4)
    if len(ran) < len(expected) and len(ran.split()) >= 2:  # cut short at a damaged `*`
        if _edit_distance(expected[: len(ran)], ran, limit) <= limit:
            return True
    # (A shorter line may also be one with bytes dropped and flipped: `Y94 E80.00` ran as
    # `Y9 E80.4`, a drop of 4, a 0 flipped to 4 and a drop of 0, whose XORs cancel.)
    return _edit_distance(expected, ran, limit) <= limit


def _edit_distance(a: str, b: str, limit: int) -> int:
    """Levenshtein distance, or limit + 1 once it is sure to be more than `limit`."""
    if abs(len(a) - len(b)) > limit:
        return limit + 1
    previous = list(range(len(b) + 1))
    for i, x in enumerate(a, 1):
        current = [i]
        for j, y in enumerate(b, 1):
            current.append(min(previous[j] + 1, current[j - 1] + 1, previous[j - 1] + (x != y)))
        if min(current) > limit:
            return limit + 1
        previous = current
    return previous[-1]


def _align(a: list[str], b: list[str]) -> tuple[list[tuple[int, int]], bool]:
    """Pairs (i, j) with a[i] == b[j], increasing in both, as many as can be found; and
    whether some stretch was too different to align."""
    n, m = len(a), len(b)
    # A common prefix is matched as Myers would. Not a common suffix: Myers matches as early as
    # it can, so that of two runs of a command the later is the repeat.
    start = 0
    while start < n and start < m and a[start] == b[start]:
        start += 1
    pairs = [(i, i) for i in range(start)]
    whole, approximate = _align_stretch(a[start:], b[start:])
    if not approximate:
        return pairs + [(start + x, start + y) for x, y in whole], False
    # Too many differences to align in one go: split the work at lines unique on both sides.
    approximate = False
    i0, j0 = start, start
    anchors = [(start + i, start + j) for i, j in _anchors(a[start:], b[start:])]
    for i, j in anchors + [(n, m)]:
        between, rough = _align_stretch(a[i0:i], b[j0:j])
        pairs += [(i0 + x, j0 + y) for x, y in between]
        approximate |= rough
        pairs.append((i, j))
        i0, j0 = i + 1, j + 1
    return pairs[:-1], approximate


def _anchors(a: list[str], b: list[str]) -> list[tuple[int, int]]:
    """The longest in-order run of lines that occur exactly once in a and once in b."""
    count_a, count_b = Counter(a), Counter(b)
    where_b = {line: j for j, line in enumerate(b) if count_b[line] == 1}
    candidates = [(i, where_b[line]) for i, line in enumerate(a)
                  if count_a[line] == 1 and line in where_b]
    # Longest increasing subsequence of j (patience sorting, with back links).
    tails: list[int] = []  # tails[r]: candidate ending the best run of length r + 1
    tail_js: list[int] = []
    back: list[int | None] = []
    for c, (_, j) in enumerate(candidates):
        r = bisect.bisect_left(tail_js, j)
        back.append(tails[r - 1] if r else None)
        if r == len(tails):
            tails.append(c)
            tail_js.append(j)
        else:
            tails[r] = c
            tail_js[r] = j
    run = []
    link = tails[-1] if tails else None
    while link is not None:
        run.append(candidates[link])
        link = back[link]
    return run[::-1]


def _align_stretch(a: list[str], b: list[str]) -> tuple[list[tuple[int, int]], bool]:
    """A longest common subsequence by the cheaper exact method, or ([], True) if too costly."""
    if not a or not b:
        return [], False
    surplus = Counter(a)
    surplus.subtract(b)
    edits = sum(map(abs, surplus.values()))  # at least this many: each surplus line is one
    if edits > MAX_EDITS:
        return [], True
    if len(a) * len(b) <= edits * edits // 2:  # Myers would take at least edits² / 2 steps
        return _table(a, b), False
    pairs = _myers(a, b, MAX_EDITS)
    return ([], True) if pairs is None else (pairs, False)


def _table(a: list[str], b: list[str]) -> list[tuple[int, int]]:
    """Pairs of a longest common subsequence by the textbook table, matching as early as it can:
    the cheaper method when one side is short (a job's layer against a journal's few lines)."""
    n, m = len(a), len(b)
    rows = [[0] * (m + 1) for _ in range(n + 1)]  # rows[i][j]: the length for a[i:] and b[j:]
    for i in range(n - 1, -1, -1):
        row, below = rows[i], rows[i + 1]
        for j in range(m - 1, -1, -1):
            row[j] = below[j + 1] + 1 if a[i] == b[j] else max(below[j], row[j + 1])
    pairs = []
    i = j = 0
    while i < n and j < m:
        if a[i] == b[j]:
            pairs.append((i, j))
            i += 1
            j += 1
        elif rows[i + 1][j] >= rows[i][j + 1]:
            i += 1
        else:
            j += 1
    return pairs


def _myers(a: list[str], b: list[str], max_edits: int) -> list[tuple[int, int]] | None:
    """Pairs of a longest common subsequence (Myers 1986, "An O(ND) difference algorithm"), or
    None when more than `max_edits` deletions and insertions separate a and b."""
    n, m = len(a), len(b)
    if abs(n - m) > max_edits:
        return None
    limit = min(max_edits, n + m)
    offset = limit + 1
    v = [0] * (2 * offset + 1)  # v[offset + k]: furthest x reached on diagonal k = x - y
    trace = []  # before each round d: v on diagonals -d-1 .. d+1
    for d in range(limit + 1):
        trace.append(v[offset - d - 1:offset + d + 2])
        for k in range(-d, d + 1, 2):
            if k == -d or (k != d and v[offset + k - 1] < v[offset + k + 1]):
                x = v[offset + k + 1]  # down: b[y - 1] inserted
            else:
                x = v[offset + k - 1] + 1  # right: a[x - 1] deleted
            y = x - k
            while x < n and y < m and a[x] == b[y]:
                x += 1
                y += 1
            v[offset + k] = x
            if x >= n and y >= m:
                return _backtrack(trace, n, m)
    return None


def _backtrack(trace: list[list[int]], n: int, m: int) -> list[tuple[int, int]]:
    pairs = []
    x, y = n, m
    for d in range(len(trace) - 1, -1, -1):
        v = trace[d]
        k = x - y
        zero = d + 1  # where diagonal 0 is in this round's slice
        if k == -d or (k != d and v[zero + k - 1] < v[zero + k + 1]):
            previous = k + 1
        else:
            previous = k - 1
        px = v[zero + previous]
        py = px - previous
        while x > px and y > py:
            x -= 1
            y -= 1
            pairs.append((x, y))
        x, y = px, py
    pairs.reverse()
    return pairs
