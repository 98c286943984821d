"""Whether a process still exists: the one question the pools' workers (:func:`hystfit.parallel._end_with`)
and the staged output directories of killed commands (:func:`hystfit.io.staged_output_dir`) ask."""

from __future__ import annotations

import os


def alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine (a zombie counts: it has not been reaped)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, owned by another user
        return True
    return True
