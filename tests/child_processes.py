"""Following a command-line run in a child process (Linux /proc), for the tests that interrupt one."""

import signal
from pathlib import Path


def handles_sigterm(pid: int) -> bool:
    """The CLI is running its command: it installed its SIGTERM handler (bit 15 of SigCgt)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return bool(int(line.split()[1], 16) >> (signal.SIGTERM - 1) & 1)
    except OSError:
        pass
    return False


def default_sigint():
    """In the child: Ctrl-C as a terminal delivers it (a shell starts background jobs, and so
    maybe this test, with SIGINT ignored, which a Python program keeps)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
