"""Imported only by the local backend's forkserver (``local.PRELOAD``): it ignores SIGTERM and
SIGHUP, as the workers ignore the stops meant for their sweep.

``timeout``, job schedulers and a closed terminal signal the whole process group. A forkserver
child's exit status reaches the sweep through the forkserver, so with the forkserver dead the
sweep takes its workers for ended: it would exit while they still save the interaction they are
in, and their watchdog would then stop them at once, losing it. The forkserver ends with the
sweep anyway (its pipe from the sweep closes); the workers set their own handlers (``_child``).
"""

import signal

signal.signal(signal.SIGTERM, signal.SIG_IGN)
signal.signal(signal.SIGHUP, signal.SIG_IGN)
