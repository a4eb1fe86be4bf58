"""The end-of-day command kept on a leash (#42 item 9: lfstudio/support/children.py): at the time limit
its group and what left it (setsid) are ended, a background process holding its output does not make
anyone wait past the limit, and its output costs bounded memory and log lines. Real processes; every
wait is the function returning (the test's timeout only guards against a hang)."""

from __future__ import annotations

import os

from lfstudio.support.children import HEAD_LINES, KEEP_BYTES, MAX_LINE_CHARS, TAIL_LINES, run_contained
from tests.scankill import gone


def test_a_setsid_grandchild_is_ended_at_the_time_limit(tmp_path):
    pids = tmp_path / "pids"
    said: list[str] = []
    result = run_contained(f"setsid sh -c 'echo $$ >> {pids}; exec sleep 600' > /dev/null 2>&1 & "
                           f"echo $$ >> {pids}; echo started; sleep 600", limit_s=1, on_line=said.append)
    assert result.timed_out and said == ["started"]
    numbers = [int(n) for n in pids.read_text().split()]
    assert len(numbers) == 2 and all(gone(n) for n in numbers), numbers


def test_a_background_process_holding_the_output_ends_at_the_limit_not_later(tmp_path):
    pidfile = tmp_path / "pid"
    result = run_contained(f"setsid sh -c 'echo $$ > {pidfile}; exec sleep 600' & echo lights off", limit_s=1)
    assert result.returncode == 0 and result.timed_out and result.output == "lights off\n"
    assert gone(int(pidfile.read_text()))


def test_a_command_that_ends_in_time_is_not_touched():
    said: list[str] = []
    result = run_contained("echo one; echo two >&2; exit 3", limit_s=60, on_line=said.append)
    assert (result.returncode, result.timed_out, result.killed) == (3, False, 0)
    assert said == ["one", "two"] and result.output == "one\ntwo\n"


def test_huge_output_is_kept_and_shown_with_a_cap():
    said: list[str] = []
    lines = 300_000
    result = run_contained(f"seq 1 {lines}; head -c 20000000 /dev/zero | tr '\\0' x; echo; echo last",
                           limit_s=120, on_line=said.append)
    assert result.returncode == 0 and not result.timed_out
    assert result.lines == lines + 2 and result.output_bytes > 20_000_000
    assert len(result.output) <= KEEP_BYTES + 10 and result.output.startswith("1\n2\n") and result.output.endswith("last\n")
    assert len(said) == HEAD_LINES + 1 + TAIL_LINES                   # first lines, one "… not shown", last lines
    assert said[0] == "1" and said[-1] == "last" and f"{lines + 2 - HEAD_LINES - TAIL_LINES} lines not shown" in said[HEAD_LINES]
    assert max(len(s) for s in said) <= MAX_LINE_CHARS + 10 and said[-2].endswith("…(cut)")


def test_a_command_that_cannot_start_says_why(tmp_path):
    result = run_contained("true", limit_s=5, cwd=tmp_path / "missing")
    assert result.error.startswith("could not start") and result.returncode is None
    assert os.path.isdir(tmp_path)
