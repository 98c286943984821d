"""Where a resolution check's refit of a named effect starts (:func:`hystfit.diagnose._started`)."""

import numpy as np

from hystfit.blocks.dynamics import Dynamics
from hystfit.diagnose import _started


def test_a_start_outside_the_configured_range_refits_the_coarse_links_widened_effect():
    """A stage widened below the default f_n range on the coarse base (124 Hz under a 160 Hz bound)
    is refitted with its widened range around its φ, not clipped onto the default's bound (a
    review's find: the clipped start then searched a whole grid again, 140 scores against 9)."""
    default = Dynamics(fn_min_Hz=160.0, fn_max_Hz=4500.0)
    widened = Dynamics(fn_min_Hz=39.9, fn_max_Hz=4500.0)
    eff, phi, key = _started(default, (np.array([124.0, 0.17]), widened))
    assert eff is widened and phi.tolist() == [124.0, 0.17]
    inside, phi2, key2 = _started(default, (np.array([600.0, 0.17]), widened))
    assert inside is default and phi2[0] == 600.0
    assert key != key2 and key[0] == np.array([124.0, 0.17]).tobytes()
    assert _started(default, None) == (default, None, ())
