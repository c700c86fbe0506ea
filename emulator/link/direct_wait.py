"""Waiting for a link's next bytes without a round through trio's scheduler while trio has
nothing else to do: the printer's answer to a host that sends one line at a time.

This module is the one place where fake-marlin reads a dependency's private state: trio's run
state (the runner, its run queue, deadlines, idle waiters, instruments and epoll object, each
task's schedule count). It does so only on the trio releases in VERIFIED_TRIO, on which the
test suite passed with it (tests/test_direct_wait.py, and the end-to-end runs over ptys); on
any other trio, or with FAKE_MARLIN_WAITS=trio, it imports nothing private and every wait is
trio's own `wait_readable`: slower, never wrong. `fake-marlin --version` says which are in use.

Why. Between two commands the printer sleeps for as long as the host takes to read the answer
and send the next line (150 µs and more), and wakes up cold. Woken through trio
(`wait_readable`: an epoll registration, a round of the run loop, the switch back into the
task), the bench's bare responder cost 83 µs of CPU per command where a plain select() loop
cost 44 µs; waiting as below, 58 µs (our host streaming 2,000 moves, four rounds side by side).
`fake-marlin bench --only hosts,cpu` measures both kinds of wait side by side.

How. When no task is due to run, nobody waits for idleness (`wait_all_tasks_blocked`, a
MockClock's autojump) and the next deadline is still ahead, trio's next step would be one
epoll_wait on its own epoll, with the time to that deadline as its timeout. We make that wait
ourselves, as one poll(2) on the link's fd and trio's epoll fd together, with the same timeout:
- our fd woke us: its bytes are read and handled now, in this task, with no task switch;
- anything else did (another fd trio waits for, a signal, a thread's `run_sync_soon`: all make
  trio's epoll fd readable) or the deadline came: we await trio's own `wait_readable`, and
  trio's loop does what it would have done, our fd among the rest.
So nothing trio would have run runs later than it would have, by more than the poll's
millisecond rounding of the timeout, which trio's own epoll_wait has too. A cancelled task is
told so at once (`checkpoint_if_cancelled`, before the wait), as at any checkpoint.

"No task is due" means more than an empty run queue: the tasks woken in the same round as
this one wait in a list of trio's loop until their turn (see `_alone`).

Verifying a new trio release: add it to VERIFIED_TRIO and run `python -m tests.verify_trio
VERSION` (this checkout and that trio in a venv of their own; the direct-wait tests and the
end-to-end runs over ptys and TCP). A release whose run state no longer has the shape read
here fails there (and `_RunnerView.of` turns the waits off rather than misread it).
"""

import functools
import math
import os
import select
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import trio

# The releases the suite has verified direct waits on. Older ones lack the run state read here
# in this shape (before 0.30 it was laid out otherwise); newer ones are unknown until verified.
VERIFIED_TRIO = ("0.30.0", "0.31.0", "0.32.0", "0.33.0", "0.34.0", "0.35.0")
WAITS_VARIABLE = "FAKE_MARLIN_WAITS"  # `trio`: trio's own waits, even on a verified trio


@functools.cache
def waits_in_use() -> tuple[bool, str]:
    """Whether links may wait directly in this process, and why, in words for --version."""
    version = trio.__version__
    if os.environ.get(WAITS_VARIABLE, "").strip().lower() == "trio":
        return False, f"trio {version}: trio's own waits ({WAITS_VARIABLE}=trio)"
    if version not in VERIFIED_TRIO:
        return False, (f"trio {version}: trio's own waits (direct waits are verified on trio "
                       f"{VERIFIED_TRIO[0]} to {VERIFIED_TRIO[-1]} only)")
    if _run_context() is None:
        return False, f"trio {version}: trio's own waits (its run state is not where it was)"
    return True, f"trio {version}: direct waits (a verified release; {WAITS_VARIABLE}=trio turns them off)"


@functools.cache
def _run_context() -> Any:
    """trio's run context, imported only on a verified release (None where it is not there)."""
    try:
        from trio._core._run import GLOBAL_RUN_CONTEXT
    except ImportError:  # pragma: no cover - a verified release has it
        return None
    return GLOBAL_RUN_CONTEXT


MAX_TASKS = 256  # past this many tasks (a printer has about 10), every wait is trio's
_MAX_TIMEOUT = 86400.0  # trio's own cap on one wait (seconds)
_READY = select.POLLIN | select.POLLPRI | select.POLLERR | select.POLLHUP | select.POLLNVAL


@dataclass(frozen=True)
class _RunnerView:
    """What a direct wait reads of one trio run, looked up once per run."""

    runner: Any
    runnable: Any  # the run queue (a deque): empty when no task is runnable
    next_deadline: Callable[[], float]
    sleep_time: Callable[[float], float]  # the clock's deadline_to_sleep_time
    epoll_fd: int
    # The instruments by hook: the dict inside trio's Instruments (a UserDict, whose own `in`
    # is a Python call), changed in place as instruments come and go.
    instrumented_hooks: dict[str, Any]

    @classmethod
    def of(cls, runner: Any) -> "_RunnerView | None":
        """None where trio's runner is not as this module expects, or in guest mode (where
        trio waits in a thread of its own, and the host loop must not be blocked)."""
        try:
            if runner.is_guest:
                return None
            # What the waits read, looked at once here: a missing one fails now, not mid-wait.
            task = trio.lowlevel.current_task()
            _ = (len(runner.waiting_for_idle), len(runner.tasks), task._schedule_points + 0,
                 task._next_send_fn, float(runner.clock_autojump_threshold))
            hooks = runner.instruments.data
            if not isinstance(hooks, dict):
                return None
            return cls(runner, runner.runq, runner.deadlines.next_deadline,
                       runner.clock.deadline_to_sleep_time, runner.io_manager._epoll.fileno(),
                       hooks)
        except (AttributeError, TypeError, ValueError, OSError):
            return None


def _current_runner() -> Any:
    return getattr(_run_context(), "runner", None) if waits_in_use()[0] else None


class DirectWait:
    """Waits until one file descriptor is readable, directly when trio is otherwise idle."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self._view: _RunnerView | None = None
        self._runner: Any = None  # the run _view belongs to (None: not looked up yet)
        # The task last found alone, and its step count then (see _alone).
        self._alone_task: trio.lowlevel.Task | None = None
        self._alone_steps = -1
        self._poll = select.poll()
        self._context = _run_context() if waits_in_use()[0] else None  # None: trio's waits

    async def readable(self) -> None:
        """Return once the fd is readable (or failed, or is being closed: trio's
        ClosedResourceError, as from `wait_readable`)."""
        # Cancellation is looked for before the wait rather than after: nothing can cancel
        # this task during a direct wait (no other task runs; a deadline ends the wait, and
        # trio's wait then delivers it), and the host's bytes are handled a few µs sooner.
        await trio.lowlevel.checkpoint_if_cancelled()
        if self.waited_directly():
            return
        await trio.lowlevel.wait_readable(self.fd)

    def waited_directly(self) -> bool:
        """Wait directly if trio has nothing else due: True once the fd is readable, False
        (having waited for nothing, or for what else trio now has to do) where the caller must
        await readable()."""
        context = self._context
        if context is None:
            return False
        # The checks of _current_view and _alone are made here first, without the calls, in
        # the usual case: the same run, and this task not suspended since it was found alone.
        runner = getattr(context, "runner", None)
        view = self._view if runner is self._runner else self._current_view()
        if view is None or view.runnable:
            return False
        runner = view.runner
        hooks = view.instrumented_hooks
        if runner.waiting_for_idle or "before_io_wait" in hooks or "after_io_wait" in hooks:
            return False  # they expect to hear of, or around, trio's own wait
        task = context.task
        if not (task._schedule_points == self._alone_steps and task is self._alone_task
                or self._alone(runner)):
            return False
        deadline = view.next_deadline()
        # No deadline (a printer idle in simulated time): trio would wait its longest.
        timeout = _MAX_TIMEOUT if deadline == math.inf else min(view.sleep_time(deadline),
                                                                 _MAX_TIMEOUT)
        if not timeout > 0 or runner.clock_autojump_threshold < timeout:
            return False
        events = self._poll.poll(timeout * 1000)  # milliseconds, rounded up as trio's are
        return len(events) == 1 and events[0][0] == self.fd and bool(events[0][1] & _READY)

    def _alone(self, runner: Any) -> bool:
        """Whether no other task is due to run. An empty run queue says so only once trio has
        run the rest of the batch this task was woken in: tasks woken with it wait in a list
        of trio's loop, not in the queue. So the first time after this task has been suspended,
        look at every task for one that is scheduled (at most MAX_TASKS: a large farm waits
        through trio); until it is suspended again, nothing new can be due but through the
        run queue."""
        task = trio.lowlevel.current_task()
        steps = task._schedule_points  # how often trio has suspended and resumed this task
        if task is self._alone_task and steps == self._alone_steps:
            return True
        tasks = runner.tasks
        if len(tasks) > MAX_TASKS or any(t._next_send_fn is not None for t in tasks):
            return False
        self._alone_task, self._alone_steps = task, steps
        return True

    def _current_view(self) -> _RunnerView | None:
        runner = _current_runner()
        if runner is not self._runner:  # a new trio run (or the first wait)
            self._runner = runner
            self._view = None if runner is None else _RunnerView.of(runner)
            self._poll = select.poll()
            if self._view is not None:
                self._poll.register(self.fd, select.POLLIN)
                self._poll.register(self._view.epoll_fd, select.POLLIN)
        return self._view


def direct_waits_available() -> bool:
    """Whether, inside this trio run, waits can be made directly (False on a trio release not
    verified, with FAKE_MARLIN_WAITS=trio, or where this trio's run state changed shape)."""
    runner = _current_runner()
    return runner is not None and _RunnerView.of(runner) is not None
