"""The terminal progress bar: redrawn on a terminal, one line per update in a file."""

from __future__ import annotations

import io

from inhand_exp.progress import ProgressBar, duration


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_duration_formats():
    assert [duration(s) for s in (5, 65, 3725, float("inf"), -1)] == [
        "5s", "1m05s", "1h02m", "--", "--"]


def test_file_gets_one_line_per_update_with_counts_rate_and_eta():
    out = io.StringIO()
    bar = ProgressBar(100, "frames", start=20, stream=out)
    bar.update(60, "success 50.0%")
    bar.update(100)
    bar.close()
    first, second = out.getvalue().splitlines()
    assert first.startswith("[" + "#" * 14 + "-" * 10 + "]  60/100 frames  success 50.0%")
    assert "frames/s  ETA" in first and second.endswith("ETA 0s")


def test_terminal_line_is_redrawn_and_disabled_bar_is_silent():
    tty = Tty()
    bar = ProgressBar(10, "episodes", stream=tty)
    bar.update(3)
    bar.update(4)
    bar.close()
    assert tty.getvalue().count("\r") == 2 and tty.getvalue().endswith("\n")
    quiet = io.StringIO()
    ProgressBar(10, "episodes", stream=quiet, enabled=False).update(3)
    assert quiet.getvalue() == ""
