"""The progress line: counts, failures and a rate; plain lines in logs, one redrawn line on a terminal."""

import io

from camcal.base.progress import Progress


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_log_lines_count_done_and_failed_items():
    stream = io.StringIO()
    bar = Progress(4, label="batch", unit="frames", stream=stream, log_interval_s=0.0)
    bar.advance()
    bar.advance(failed=True)
    bar.advance()
    bar.close()
    lines = stream.getvalue().splitlines()
    assert len(lines) == 4 and "\r" not in stream.getvalue()
    assert lines[-1].startswith("batch [##################------] 3/4") and "1 failed" in lines[-1]
    assert "frames/s" in lines[-1] and "ETA" in lines[-1]
    assert bar.done == 2 and bar.failed == 1 and bar.rate > 0


def test_terminal_redraws_one_line_and_disabled_draws_nothing():
    terminal = _Terminal()
    bar = Progress(2, label="x", stream=terminal)
    bar.advance()
    bar.advance()
    bar.close()
    text = terminal.getvalue()
    assert text.startswith("\r") and text.endswith("\n") and text.count("\n") == 1 and "2/2" in text
    quiet = io.StringIO()
    silent = Progress(2, stream=quiet, enabled=False)
    silent.advance()
    silent.close()
    assert quiet.getvalue() == ""


def test_report_callback_sets_the_count_and_closes_at_the_total():
    stream = io.StringIO()
    bar = Progress(3, label="detecting left", unit="images", stream=stream, log_interval_s=0.0)
    for done in (1, 2, 3):
        bar.report(done, 3)
    lines = stream.getvalue().splitlines()
    assert len(lines) == 3 and lines[-1].startswith("detecting left [########################] 3/3")
    assert bar.done == 3
