"""The process's one signal boundary: SIGINT and SIGTERM are recorded where they land, never raised there.

Python's default SIGINT handler raises ``KeyboardInterrupt`` at whatever bytecode runs when the
signal lands: inside an import, inside a plugin constructor that Mitsuba calls from C++, inside a
Dr.Jit callback. An exception there leaves a half-imported module, a traceback, or a C++
``std::terminate``. Under the boundary (:func:`install`, the first thing the ``pointillist``
console script does) the handlers only record the signal:

* **first signal**: a request to stop. Work stops at the next *safe point*, a place in plain Python
  where unwinding is clean: :func:`check` raises :class:`KeyboardInterrupt` (SIGINT) or
  :class:`~pointillist.core.errors.Terminated` (SIGTERM) there, and the command line turns it into
  exit status 130 / 143 and one line on stderr. Loops that can keep their work (the passes of a
  progressive render) ask :func:`received` instead and stop after the step in flight.
* **stop now**: a second signal, or :data:`GRACE_SECONDS` after the first when the command has not
  ended by itself (a render kernel, a filter, a cluster that takes minutes does not return to
  Python; only under the console script, which owns the process: ``install(deadline=True)``): a
  watcher thread, woken through :func:`signal.set_wakeup_fd` (so it runs while the main thread is
  in native code), runs the hooks registered with :func:`on_abandon` (a progressive render
  writes the passes done) for what is left of :data:`STOP_SECONDS`, removes the temporary files of
  writes in flight (:func:`temporary_file`), prints one line and ends the process with 130 / 143.
  Whatever the console's process is doing, a signal ends it within :data:`STOP_SECONDS` (the one exception:
  a native call that holds the interpreter's lock all along; Dr.Jit's kernels and Mitsuba's
  renders release it).

Outside the boundary (library use, a notebook) nothing changes: :func:`check` does nothing, and
Python's own handlers stay.

A process can inherit SIGINT and SIGTERM *blocked* (the signal mask survives ``exec``: some CI
runners and service managers start their children that way). A blocked signal is never delivered,
so the boundary unblocks the two in the main thread while it is installed (the mask comes back when
it is removed): a command that promises 130 / 143 keeps the promise whoever started it.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from pointillist.core.errors import Terminated

__all__ = ["SIGNALS", "STATUS", "install", "uninstall", "installed", "boundary", "set_command", "received",
           "check", "status", "message", "deferred", "on_abandon", "temporary_file", "new_folders", "forget_file",
           "GRACE_SECONDS", "STOP_SECONDS", "held", "report", "finish"]

#: The signals the boundary handles.
SIGNALS = (signal.SIGINT, signal.SIGTERM)

#: Exit status after each signal: 128 + the signal number, as a shell reports it.
STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}

#: After the first signal, how long a command has to end by itself (reach a safe point, finish the
#: step in flight) before it is stopped as after a second signal (seconds).
GRACE_SECONDS = 1.0

#: A signal ends the process at most this long after it arrived (seconds): the hooks of a command
#: stopped at once get what is left of it (the line and the exit take a few milliseconds more).
STOP_SECONDS = 1.8


class _Boundary:
    """The installed state: handlers, the wake-up pipe, the watcher thread, what was received."""

    def __init__(self, deadline: bool = False) -> None:
        self.deadline = deadline  # the first signal ends the process within STOP_SECONDS (the console's)
        self.lock = threading.Lock()
        self.received: list[int] = []
        self.hooks: list[Callable[[], None]] = []
        self.temporary: set[str] = set()
        self.folders: list[str] = []  # folders made for writes in flight (removed when still empty)
        self.command = "pointillist"
        self.read_fd, self.write_fd = os.pipe()
        for fd in (self.read_fd, self.write_fd):
            os.set_blocking(fd, False)
        self.previous_wakeup = signal.set_wakeup_fd(self.write_fd, warn_on_full_buffer=False)
        self.previous = {signum: signal.signal(signum, _record) for signum in SIGNALS}
        self.stopping = False
        self.ending = False    # the watcher is stopping the process (abandon)
        self.reported = False  # the line about the signal was printed (report)
        self.watcher = threading.Thread(target=self._watch, name="pointillist-signals", daemon=True)
        self.watcher.start()
        # unblock the two (an inherited blocked mask would hold them for ever); the watcher keeps
        # the mask it was started with, so the signals land in the main thread as before
        self.previous_mask = (signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)
                              if hasattr(signal, "pthread_sigmask") else None)

    # -- the pipe: every signal lands there as one byte (written by Python's C-level handler)
    def drain(self) -> None:
        """Move what the pipe holds into :attr:`received` (call with :attr:`lock` held)."""
        while True:
            try:
                data = os.read(self.read_fd, 512)
            except BlockingIOError:
                return
            if not data:
                return
            self.received.extend(b for b in data if b in STATUS)

    def _watch(self) -> None:
        first_at = None  # when the watcher saw the first signal (monotonic seconds)
        while not self.stopping:
            timeout = None if first_at is None else max(first_at + GRACE_SECONDS - time.monotonic(), 0.0)
            try:
                select.select([self.read_fd], [], [], timeout)
            except (OSError, ValueError):  # the pipe was closed by uninstall()
                return
            with self.lock:
                if self.stopping:
                    return
                self.drain()
                count = len(self.received)
            if count and first_at is None and self.deadline:
                first_at = time.monotonic()
            if count >= 2 or (first_at is not None and time.monotonic() >= first_at + GRACE_SECONDS):
                # the hooks' time ends STOP_SECONDS after the first signal (the grace included);
                # without a deadline, what is left after a grace from the second signal on
                end = (first_at if first_at is not None else time.monotonic() - GRACE_SECONDS) + STOP_SECONDS
                self.abandon(count >= 2, end)

    def abandon(self, second: bool, end: float) -> None:
        """Stop now: run the hooks until ``end`` (monotonic seconds) at most, remove temporary files, one line, exit.

        From here on the main thread's lines go nowhere (stderr is pointed at ``/dev/null``: an
        error it meets while being stopped is not news) and it cannot end the process by itself
        (:func:`finish` waits); temporary files made from now on are made after the removal
        (:func:`temporary_file` waits for the lock held until the exit).
        """
        with self.lock:
            hooks, first, command = list(self.hooks), self.received[0], self.command
            self.ending = True
        with contextlib.suppress(OSError):
            sys.stderr.flush()
        stderr = os.dup(2)
        with contextlib.suppress(OSError), open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        runner = threading.Thread(target=_run_hooks, args=(hooks,), daemon=True)
        runner.start()
        runner.join(max(end - time.monotonic(), 0.0))
        self.lock.acquire()  # never released: no temporary file is made from here on
        _end_children()
        line = b""
        if not self.reported:
            why = "second signal" if second else f"it did not stop within {GRACE_SECONDS:g} s"
            line = f"{command}: {message(first)}; stopped at once ({why})\n".encode()
        _remove_and_exit([os.fsencode(name) for name in self.temporary],
                         [os.fsencode(name) for name in reversed(self.folders)], stderr, line, STATUS[first])

    def close(self) -> None:
        self.stopping = True
        signal.set_wakeup_fd(self.previous_wakeup)
        for signum, handler in self.previous.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)
        with contextlib.suppress(OSError):
            os.write(self.write_fd, b"\0")  # wakes the watcher, which sees `stopping`
        self.watcher.join(5)
        if self.previous_mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, self.previous_mask)
        for fd in (self.read_fd, self.write_fd):
            with contextlib.suppress(OSError):
                os.close(fd)


_STATE: _Boundary | None = None


def _record(signum, frame) -> None:
    """The Python-level handler: nothing (the C-level handler already wrote the signal into the
    wake-up pipe; a Python handler must exist for it to do so). Never raises."""


def _run_hooks(hooks) -> None:
    for hook in hooks:
        try:
            hook()
        except BaseException:  # noqa: BLE001 - the process is ending; a failing hook must not stop that
            pass


def _remove_and_exit(names: list[bytes], folders: list[bytes], fd: int, line: bytes, status: int) -> None:
    """Remove the temporary files ``names`` and the ``folders`` made for them (those left empty,
    deepest first), write ``line`` to ``fd`` and end the process, without
    letting another thread run Python in between: a writer that reopens its temporary file by name
    (matplotlib, Pillow) would otherwise make it again after its removal. ``os.unlink`` lets other
    threads run during the call; libc's, called through ``ctypes.PyDLL``, keeps the interpreter
    lock, and so does every step to the exit (no forced switch either)."""
    import ctypes

    sys.setswitchinterval(1000.0)
    try:
        libc = ctypes.PyDLL(None)
        unlink, rmdir, write = libc.unlink, libc.rmdir, libc.write
    except (OSError, AttributeError):  # no libc symbols in this process: Python's own calls
        unlink, rmdir, write = os.unlink, os.rmdir, (lambda f, data, n: os.write(f, data))
    for name in names:
        with contextlib.suppress(OSError):
            unlink(name)
    for name in folders:  # rmdir removes only an empty folder
        with contextlib.suppress(OSError):
            rmdir(name)
    if line:
        with contextlib.suppress(OSError):
            write(fd, line, len(line))
    os._exit(status)


def _descendants(pid: int) -> list[int]:
    """The processes below ``pid`` (children first), read from ``/proc`` (empty where there is none)."""
    parents: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            text = stat.read_text()
            ppid = int(text[text.rindex(")") + 2:].split()[1])  # after the command name: state, ppid
            parents.setdefault(ppid, []).append(int(stat.parent.name))
    found, queue = [], [pid]
    while queue:
        children = parents.get(queue.pop(0), [])
        found += children
        queue += children
    return found


def _end_children() -> None:
    """Kill the processes this one started (Dask workers, a child render), which the exit would
    leave running for a while; not multiprocessing's resource tracker, which ends by itself when
    this process does and then removes the semaphores the workers left."""
    from multiprocessing import resource_tracker

    tracker = getattr(resource_tracker._resource_tracker, "_pid", None)
    for pid in _descendants(os.getpid()):
        if pid != tracker:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


def _print_line(text: str) -> None:
    with contextlib.suppress(Exception):
        sys.stdout.flush()
    with contextlib.suppress(Exception):
        sys.stderr.write(text + "\n")
        sys.stderr.flush()


def install(command: str | None = None, *, deadline: bool = False) -> bool:
    """Install the boundary (main thread only); True when this call installed it.

    ``deadline``: the boundary owns the process (the console script): a command that has not
    stopped :data:`GRACE_SECONDS` after the first signal is stopped at once. Without it (the command
    line run inside a notebook or a script, :func:`pointillist.cli.main`) only a second signal does
    that: an interrupted cell must not end the kernel's process. Idempotent: a second call only
    updates the command name used in the messages.
    """
    global _STATE
    if _STATE is None:
        if threading.current_thread() is not threading.main_thread():
            return False
        _STATE = _Boundary(deadline)
        installed_now = True
    else:
        installed_now = False
    if command is not None:
        _STATE.command = command
    return installed_now


def uninstall() -> None:
    """Restore the handlers the boundary replaced (what was received is forgotten)."""
    global _STATE
    if _STATE is not None:
        state, _STATE = _STATE, None
        state.close()


def installed() -> bool:
    """Whether the boundary is installed in this process."""
    return _STATE is not None


@contextlib.contextmanager
def boundary(command: str | None = None) -> Iterator[bool]:
    """The boundary for a block (installed on entry unless it already was, removed on exit if it
    was installed here); yields whether it is active (False outside the main thread)."""
    mine = install(command)
    try:
        yield installed()
    finally:
        if mine:
            uninstall()


def set_command(command: str) -> None:
    """Name the command in the line a second signal prints (``pointillist render``)."""
    if _STATE is not None:
        _STATE.command = command


def received() -> int | None:
    """The first signal received under the boundary (``signal.SIGINT`` / ``SIGTERM``), or None."""
    state = _STATE
    if state is None:
        return None
    with state.lock:
        state.drain()
        return state.received[0] if state.received else None


def check() -> None:
    """A safe point: raise ``KeyboardInterrupt`` (SIGINT) or ``Terminated`` (SIGTERM) if one was received.

    Does nothing outside the boundary.
    """
    signum = received()
    if signum == signal.SIGTERM:
        raise Terminated()
    if signum is not None:
        raise KeyboardInterrupt()


def status(signum: int | None = None) -> int:
    """The exit status of ``signum`` (default: the first signal received; 130 when none was)."""
    signum = received() if signum is None else signum
    return STATUS.get(signum, 130)


def message(signum: int) -> str:
    """What the command line says about ``signum``: ``interrupted`` or ``terminated (SIGTERM)``."""
    return "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted"


@contextlib.contextmanager
def on_abandon(hook: Callable[[], None]) -> Iterator[None]:
    """While the block runs, a second signal runs ``hook`` (in another thread) before the process ends.

    The hook may not touch what the main thread is changing; it runs until :data:`STOP_SECONDS`
    after the first signal at most (a file it is writing then is removed).
    """
    state = _STATE
    if state is None:
        yield
        return
    with state.lock:
        state.hooks.append(hook)
    try:
        yield
    finally:
        with state.lock:
            with contextlib.suppress(ValueError):
                state.hooks.remove(hook)


@contextlib.contextmanager
def deferred() -> Iterator[Callable[[], int | None]]:
    """For a loop that stops by itself after the step in flight: yields ``requested()``, the first
    SIGINT/SIGTERM received (or None).

    Under the boundary that is :func:`received`. Outside it (library use: a notebook, a script),
    in the main thread, the two signals are caught for the block: the first is only recorded; a
    second raises ``KeyboardInterrupt`` as Python's own Ctrl-C does. The previous handlers come
    back after the block.
    """
    if _STATE is not None or threading.current_thread() is not threading.main_thread():
        yield received
        return
    first: list[int] = []

    def handle(signum, frame):
        if first:
            raise KeyboardInterrupt(f"signal {signum} again")
        first.append(signum)

    previous = {signum: signal.signal(signum, handle) for signum in SIGNALS}
    try:
        yield lambda: first[0] if first else None
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)


def temporary_file(create: Callable[[], str]) -> str:
    """Call ``create()`` (which makes a temporary file and returns its name) and register the name,
    as one step that a second signal cannot cut in two: the file it ends the process in the
    middle of is removed (:func:`forget_file` when it is renamed or removed)."""
    state = _STATE
    if state is None:
        return create()
    with state.lock:
        name = create()
        state.temporary.add(str(name))
    return name


@contextlib.contextmanager
def new_folders(path: str | os.PathLike) -> Iterator[None]:
    """Make the missing folders above the file ``path`` for a write in the block: they belong to the
    write in flight, removed (when left empty) if the block fails or the process is stopped at once
    in it, kept once it succeeded. Outside the boundary only the failure removes them."""
    made, folder = [], Path(path).parent
    while not folder.exists():  # top-down, the outermost missing folder first
        made.insert(0, folder)
        folder = folder.parent
    state = _STATE
    with held():
        if state is not None:
            with state.lock:
                state.folders.extend(str(folder) for folder in made)
        for folder in made:
            folder.mkdir(exist_ok=True)
    try:
        yield
    except BaseException:
        for folder in reversed(made):
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    finally:
        if state is not None:
            with state.lock:
                for folder in made:
                    with contextlib.suppress(ValueError):
                        state.folders.remove(str(folder))


def forget_file(name: str | os.PathLike) -> None:
    """The temporary file ``name`` is gone (renamed over its target, or removed)."""
    state = _STATE
    if state is not None:
        with state.lock:
            state.temporary.discard(str(name))


def _block():
    """Block SIGINT and SIGTERM in this thread (POSIX: they stay pending); the mask to restore, or None."""
    if not hasattr(signal, "pthread_sigmask"):
        return None
    return signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)


@contextlib.contextmanager
def held() -> Iterator[None]:
    """SIGINT and SIGTERM held pending in this thread for the block, delivered after it (POSIX; elsewhere
    nothing changes): a few steps that a signal may not cut in two, such as making a temporary file and
    binding its name."""
    mask = _block()
    try:
        yield
    finally:
        if mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def report(signum: int, command: str | None = None) -> None:
    """Print the one line about ``signum`` (``pointillist render: terminated (SIGTERM)``) on stderr.

    Once per process under the boundary: a second call, or a call while the watcher stops the
    process (it prints its own line), prints nothing.
    """
    state = _STATE
    if state is None:
        _print_line(f"{command or 'pointillist'}: {message(signum)}")
        return
    with state.lock:
        if state.reported or state.ending:
            return
        state.reported = True
        _print_line(f"{command or state.command}: {message(signum)}")


def finish(exit_status: int) -> int:
    """The final exit status: a signal received before the process ends makes a success 130 / 143.

    Called last by the console script, with the signals blocked in the calling thread so that no
    signal lands between this decision and the exit; prints the one line when it changes the
    status (an error line already printed stays the only one). While the watcher stops the
    process (:data:`GRACE_SECONDS` passed, or a second signal) it waits for that: the watcher
    ends the process.
    """
    _block()
    state = _STATE
    if state is not None and state.ending:
        while True:
            time.sleep(1.0)
    signum = received()
    if signum is None and hasattr(signal, "sigpending"):  # sent, held by the mask just set: it counts
        signum = next((s for s in SIGNALS if s in signal.sigpending()), None)
    if signum is not None and exit_status == 0:
        report(signum)
        return STATUS[signum]
    return exit_status
