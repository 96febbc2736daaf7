"""Stack locks: one holder at a time across processes, released by the kernel however the holder ends."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from heoslice.errors import StackBusyError
from heoslice.locks import hold_stack

HOLD = "import sys, time; from heoslice.locks import hold_stack\nwith hold_stack(sys.argv[1], 'test'):\n" \
       "    print('held', flush=True); time.sleep(60)"


def test_a_second_holder_is_refused_with_exit_18(tmp_path):
    """While one holder has the stack, another open of it raises StackBusyError (exit 18, one line)."""
    with hold_stack(tmp_path / "s", "printing it", create=True):
        with pytest.raises(StackBusyError) as info:
            with hold_stack(tmp_path / "s", "slicing into it"):
                pass
    assert info.value.exit_code == 18 and "slicing into it" in str(info.value) and "\n" not in str(info.value)
    with hold_stack(tmp_path / "s", "slicing into it"):
        pass


def test_a_killed_holder_leaves_no_stale_lock(tmp_path):
    """A holder killed with SIGKILL releases the stack at once (flock on the directory's fd, no lock file)."""
    (tmp_path / "s").mkdir()
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(tmp_path / "s")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(StackBusyError):
            with hold_stack(tmp_path / "s", "slicing into it"):
                pass
        holder.kill()
        holder.wait(10)
        time.sleep(0.05)
        with hold_stack(tmp_path / "s", "slicing into it"):
            pass
        assert list((tmp_path / "s").iterdir()) == []
    finally:
        if holder.poll() is None:
            holder.kill()
        holder.stdout.close()
