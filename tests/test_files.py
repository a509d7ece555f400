"""The ground-layer file and terminal rules: pointillist.core.files (output check, atomic writes),
pointillist.core.terminal (when a progress bar is drawn) and signals.held (the mask of atomic_write)."""

from __future__ import annotations

import io
import os
import signal
import sys
import threading

import pytest

from pointillist.core.errors import UsageError


class _Stream(io.StringIO):
    def __init__(self, tty: bool):
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def test_a_bar_is_drawn_only_when_asked_for_and_on_a_terminal():
    from pointillist.core.terminal import draws_progress

    assert draws_progress(True, _Stream(True)) is True
    assert draws_progress(False, _Stream(True)) is False      # not asked for
    assert draws_progress(True, _Stream(False)) is False      # a log file, a pipe
    assert draws_progress(True, io.StringIO()) is False       # a notebook's captured output
    closed = io.StringIO()
    closed.close()
    assert draws_progress(True, closed) is False              # isatty on a closed stream raises ValueError
    assert draws_progress(True, object()) is False            # no isatty at all


def test_a_bar_off_a_terminal_counts_without_drawing(monkeypatch):
    from pointillist.core.terminal import progress_bar

    err = _Stream(False)
    monkeypatch.setattr(sys, "stderr", err)
    with progress_bar(range(5), progress=True, desc="frames") as bar:
        assert sum(bar) == 10
    assert bar.disable and bar.n == 0 and err.getvalue() == ""  # disabled tqdm neither draws nor counts
    with progress_bar(total=4, progress=True, desc="tasks") as bar:
        bar.update(4)
    assert err.getvalue() == ""


def test_check_output_path_refuses_each_kind_of_bad_output(tmp_path):
    from pointillist.core.files import check_output_path, mark_input

    good = tmp_path / "a.exr"
    assert check_output_path(good, name="--output") == good
    with pytest.raises(UsageError, match=r"^--output: .* is a folder, expected a file name$"):
        check_output_path(tmp_path, name="--output")
    with pytest.raises(UsageError, match=r"^--output: /dev/null exists and is not a regular file$"):
        check_output_path("/dev/null", name="--output")
    with pytest.raises(UsageError, match=r"^--output: folder .*missing does not exist$"):
        check_output_path(tmp_path / "missing" / "a.exr", name="--output")
    assert check_output_path(tmp_path / "missing" / "deeper" / "a.exr", make_parent=True).name == "a.exr"
    (tmp_path / "file").write_text("x")
    with pytest.raises(UsageError, match=r"^--output: .*file is not a folder$"):
        check_output_path(tmp_path / "file" / "a.exr", name="--output", make_parent=True)
    scene = tmp_path / "scene.xml"
    scene.write_text("<scene/>")
    with pytest.raises(UsageError, match="refusing to overwrite the input file"):
        check_output_path(scene, inputs=[scene])
    link = tmp_path / "link.xml"
    link.symlink_to(scene)
    with pytest.raises(UsageError, match="refusing to overwrite the input file"):  # the same file by inode
        check_output_path(link, inputs=[scene])
    folder = tmp_path / "series"
    folder.mkdir()
    with pytest.raises(UsageError, match="lies in the input folder"):
        check_output_path(folder / "x.png", inputs=[folder])
    read = tmp_path / "read.exr"
    read.write_bytes(b"")
    check_output_path(read)
    mark_input(read)                                           # a file this process read is an input
    with pytest.raises(UsageError, match="refusing to overwrite the input file"):
        check_output_path(read)
    assert issubclass(UsageError, ValueError)


def test_the_plan_checks_an_outputs_suffix_before_any_work(tmp_path):
    from pointillist.plan import Output, Plan

    Plan(outputs=[Output(tmp_path / "a.PNG", "--output", suffixes=(".png", ".exr"))]).check()  # any case
    with pytest.raises(UsageError, match=r"^--plot-file: expected a \.png file name, got .*a\.exr$"):
        Plan(outputs=[Output(tmp_path / "a.exr", "--plot-file", suffixes=(".png",))]).check()


def test_save_figure_checks_the_path_and_closes_the_figure(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pointillist.core.files import save_figure

    fig = plt.figure(figsize=(1, 1))
    save_figure(fig, tmp_path / "f.png", dpi=20)
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not plt.fignum_exists(fig.number)
    fig = plt.figure(figsize=(1, 1))
    with pytest.raises(UsageError, match="^--plot: refusing to overwrite the input file"):
        save_figure(fig, tmp_path / "f.png", inputs=[tmp_path / "f.png"], name="--plot")
    assert not plt.fignum_exists(fig.number)                   # closed on failure too
    assert sorted(os.listdir(tmp_path)) == ["f.png"]           # no temporary file left


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks")
def test_held_signals_wait_for_the_end_of_the_block():
    from pointillist.core import signals

    got = []
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: got.append(signum))
    mask = signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGTERM])  # whatever ran before
    got.clear()
    try:
        with signals.held():
            signal.pthread_kill(threading.get_ident(), signal.SIGTERM)  # to this thread, which holds it
            assert signal.SIGTERM in signal.sigpending() and got == []
        for _ in range(1000):                                   # delivered at the next bytecode check
            if got:
                break
        assert got == [signal.SIGTERM]
        assert signal.SIGTERM not in signal.pthread_sigmask(signal.SIG_BLOCK, [])  # the mask is restored
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        signal.signal(signal.SIGTERM, previous)
