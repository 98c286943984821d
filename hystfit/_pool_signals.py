"""The first module the pools' fork server imports (:data:`hystfit.parallel.POOL_PRELOAD`): Ctrl-C
ignored from the server's start.

Ctrl-C reaches the whole process group, the fork server too. multiprocessing's server ignores
SIGINT only once it has imported its preload modules, which takes the first seconds
(:mod:`hystfit._pool_preload`: numba, scipy); a Ctrl-C then printed the server's KeyboardInterrupt
traceback (from ``import numba``) after the command's one line (a blind test's find). The command
alone decides (it stops its pool), as every worker does (``parallel._init_worker``). A module of
its own: only the server imports it (another process importing :mod:`hystfit._pool_preload`, a
test, keeps its Ctrl-C).
"""

import signal

signal.signal(signal.SIGINT, signal.SIG_IGN)
