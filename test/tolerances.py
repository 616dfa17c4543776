"""Tolerances and time bounds used by more than one test file, each named once with its reason.

A file that needs a bound of its own keeps it next to its test; a bound two
files share lives here, so the two cannot drift apart.
"""

import numpy as np

# --- Time: deadlines that only bound a hang ------------------------------------------

#: How much later than its own deadline a call may return before a test calls it hung.
#: A loaded 2-core machine can hold a thread back for a second or more; a client that
#: ignored its deadline would be late by far more, or never return. Never a speed bar.
HANG_MARGIN_S = 10.0
#: After the expected messages, a probe listens this long for any that should not come
#: (a message that does come later only makes such a test pass less strictly, never fail).
QUIET_S = 1.0

# --- Encoder read-back of the simulated controller -----------------------------------

#: The simulated controller's encoder: a fixed offset plus uniform noise of this
#: half-width per axis (turntable, carriage), degrees (the simulator's defaults and
#: config/mock_hardware.yaml).
ENCODER_OFFSET_DEG = (0.03, -0.02)
ENCODER_NOISE_DEG = (0.01, 0.01)
#: GRBL prints positions and G-code targets with 3 decimals: half a unit of the last one.
PRINT_ROUNDING_DEG = 0.0005
#: Read-back of an axis at rest at its target, per axis (turntable, carriage), radians:
#: printing + offset + noise, plus float round-off of the degree/radian conversions.
READBACK_TOL_RAD = np.radians(PRINT_ROUNDING_DEG + np.abs(ENCODER_OFFSET_DEG)
                              + ENCODER_NOISE_DEG) + 1e-12
