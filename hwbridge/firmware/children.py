"""Child programs that go when hwbridge goes (avrdude, QEMU).

They run in process groups of their own, so that a Ctrl-C at a terminal reaches hwbridge, which
then stops them in order. A hwbridge that is killed outright (SIGKILL, an out-of-memory kill, a
test runner's timeout) runs no clean-up, and such a child lived on: an avrdude spinning on a
port for half an hour, a QEMU holding its pty. :func:`follow_parent` starts them through
util-linux's ``setpriv --pdeathsig KILL`` (Linux's ``PR_SET_PDEATHSIG``), so the kernel ends
them with us.
"""

from __future__ import annotations

import shutil
import threading

__all__ = ["follow_parent"]


def follow_parent(argv: list[str]) -> list[str]:
    """``argv``, run so that the kernel kills it when this process dies. The signal is tied to
    the thread that starts the child, so this is only done from the main thread (which lives
    as long as the process); elsewhere, and where ``setpriv`` is missing, ``argv`` as it is."""
    setpriv = shutil.which("setpriv")
    if setpriv is None or threading.current_thread() is not threading.main_thread():
        return argv
    return [setpriv, "--pdeathsig", "KILL", *argv]
