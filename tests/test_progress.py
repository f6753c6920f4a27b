"""The progress bar (gamma/driver/outputs/progress.py): its line, its drawing in
place, and a stderr that refuses writes, which must never stop a run."""

import io
import os
import re

from gamma.driver.outputs.progress import ProgressBar, clock, progress


def test_clock_is_minutes_and_seconds_then_hours():
    assert clock(0) == "00:00"
    assert clock(59.9) == "00:59"
    assert clock(61) == "01:01"
    assert clock(3600 + 61) == "1:01:01"


def test_the_line_fills_its_width_with_the_bar_in_proportion():
    bar = ProgressBar(5, unit=" iteration", file=io.StringIO())
    bar.update(2)
    bar.set_postfix_str("0.61 s trace, 397k hitting γ-tons/s")
    line = bar.line(100)
    assert len(line) == 99                                    # a line as wide as the terminal would wrap
    m = re.fullmatch(r" 40%\|(.*)\| 2/5 iteration \[\d\d:\d\d<\d\d:\d\d\], 0\.61 s trace, 397k hitting γ-tons/s",
                     line)
    assert m, line
    cells = m[1]
    assert cells.count("█") == int(len(cells) * 0.4)        # 2 of 5: two fifths of the cells
    assert cells.rstrip(" ▏▎▍▌▋▊▉").count(" ") == 0         # full cells, then one partial, then blanks
    bar.update(3)
    assert set(re.search(r"\|(.*)\|", bar.line(100))[1]) == {"█"}
    assert bar.line(100).startswith("100%|")


def test_the_bar_is_redrawn_in_place_and_ends_its_line():
    out = io.StringIO()
    bar = ProgressBar(3, desc="export", file=out)
    for _ in range(3):
        bar.update(1)
    bar.close()
    bar.close()                                               # a second close writes nothing
    text = out.getvalue()
    assert text.count("\r") == 4 and text.endswith("\n") and text.count("\n") == 1
    assert [re.match(r"export: +\d+%", part) is not None for part in text.strip().split("\r")] == [True] * 4
    assert "3/3 iteration" in text.split("\r")[-1]


def test_a_shorter_line_blanks_the_rest_of_the_longer_one(monkeypatch):
    out = io.StringIO()
    monkeypatch.setenv("COLUMNS", "120")
    bar = ProgressBar(2, file=out)
    bar.update(1)
    monkeypatch.setenv("COLUMNS", "80")                       # the terminal made narrower
    bar.update(1)
    first, second = out.getvalue().split("\r")[2:]
    assert len(first) == 119 and len(second) == 119 and second.endswith(" " * 40)
    assert len(second.rstrip(" ")) <= 79


def test_a_narrow_terminal_drops_the_postfix_then_cells_never_wraps():
    bar = ProgressBar(5, file=io.StringIO())
    bar.update(2)
    bar.set_postfix_str("0.61 s trace, 397k hitting γ-tons/s")
    wide, narrow, tiny = bar.line(120), bar.line(60), bar.line(12)
    assert wide.endswith("γ-tons/s") and len(wide) == 119
    assert "trace" not in narrow and len(narrow) == 59 and narrow.endswith("]")   # the postfix went, the bar stayed
    assert re.fullmatch(r" 40%\|█+[ ▏▎▍▌▋▊▉]* *\| 2/5 iteration \[\d\d:\d\d<\d\d:\d\d\]", narrow)
    assert len(tiny) == 11                                    # cut, never longer than the terminal


def test_the_width_is_the_bars_own_terminal_or_columns(monkeypatch):
    monkeypatch.delenv("COLUMNS", raising=False)
    assert ProgressBar(1, file=io.StringIO())._width() == 100  # not a terminal
    monkeypatch.setenv("COLUMNS", "73")
    assert ProgressBar(1, file=io.StringIO())._width() == 73

    class Terminal(io.StringIO):
        def isatty(self):
            return True

        def fileno(self):
            return 99

    monkeypatch.delenv("COLUMNS")
    monkeypatch.setattr("os.get_terminal_size", lambda fd: os.terminal_size((64, 20)) if fd == 99 else None)
    assert ProgressBar(1, file=Terminal())._width() == 64      # asked of the bar's file, not of stdout


def test_a_refused_write_stops_the_drawing_not_the_caller():
    class ClosedPipe(io.StringIO):
        writes = 0

        def write(self, text):
            ClosedPipe.writes += 1
            raise BrokenPipeError(32, "Broken pipe")

    bar = ProgressBar(4, file=ClosedPipe())
    bar.update(1)
    bar.update(1)
    bar.close()
    assert ClosedPipe.writes == 1 and not bar.drawing         # tried once, then left alone

    closed = io.StringIO()
    closed.close()                                            # ValueError: I/O on a closed file
    bar = ProgressBar(2, file=closed)
    bar.update(2)
    bar.close()
    assert not bar.drawing


def test_disabled_draws_nothing_and_progress_yields_every_item():
    out = io.StringIO()
    assert list(progress([3, 1, 2], file=out, disable=True)) == [3, 1, 2]
    assert out.getvalue() == ""
    seen = []
    for item in progress(iter(["a", "b"]), total=2, desc="export", file=out):
        seen.append((item, out.getvalue().count("\r")))
    assert seen == [("a", 1), ("b", 2)]                       # drawn before each item is handed out
    assert out.getvalue().endswith("\n") and "2/2 iteration" in out.getvalue().split("\r")[-1]


def test_a_stderr_without_block_characters_gets_an_ascii_bar():
    raw = io.BytesIO()
    ascii_err = io.TextIOWrapper(raw, encoding="ascii", errors="backslashreplace")
    bar = ProgressBar(4, file=ascii_err)
    bar.update(3)
    bar.close()
    text = raw.getvalue().decode("ascii")
    last = text.strip().split("\r")[-1]
    assert re.fullmatch(r" 75%\|#+[1-9]? *\| 3/4 iteration \[\d\d:\d\d<\d\d:\d\d\]", last), last
