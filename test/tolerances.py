"""Tolerances and time bounds used by more than one test file, each named once with its reason.

A file that needs a bound of its own keeps it next to its test; a bound two
files share lives here, so the two cannot drift apart.
"""

import numpy as np

# --- Time: deadlines that only bound a hang ------------------------------------------

#: A wait for something that should happen, or a call's overrun of its own deadline,
#: longer than this is a hang: a loaded 2-core machine can hold a thread back for seconds,
#: never for this long. It bounds a hang, never a speed.
HANG_S = 30.0
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
#: The scan's settle tolerance (config/scan.yaml ``settle_tolerance_deg``): it shoots once
#: the last readings are all this near the target and still to within it.
SETTLE_TOLERANCE_DEG = 0.1
#: A capture's encoder tag against its planned view, per axis, radians: the axes are
#: judged settled within the settle tolerance, possibly while the simulated carriage still
#: closes the last hundredths of a degree of its deceleration ramp (the tag is the reading
#: at the shutter, wherever the axis is), plus the read-back's own error. Planned views
#: lie degrees apart, so a capture still matches one view only.
CAPTURE_TOL_RAD = np.radians(SETTLE_TOLERANCE_DEG) + READBACK_TOL_RAD

# --- Reconstructions of the mug against the true object -----------------------------

#: Volume IoU of the mug meshed at 64^3 from a sparse scan (17 views in the mock cell;
#: 48 when one of the 49 is rejected): the visual hull contains the mug and adds volume
#: where no view sees in (the cup's inside, between the rings), plus half a voxel
#: (1.8 mm) of marching-cubes placement; 0.955 is measured with 29 views.
MUG_IOU_SPARSE_MIN = 0.85
#: The same from 29 exact masks on two rings and the top view, 64^3: 0.955 measured.
MUG_IOU_29_VIEWS_MIN = 0.92
#: Mean distance between the reconstructed and the true surface, in voxels: half a voxel
#: of surface placement plus the hull's extra volume in the concavities, about two.
CHAMFER_MEAN_VOXELS = 2.0
#: Mean IoU of the hull reprojected into the exact masks that carved it: the two differ
#: only in rim pixels, where a voxel's centre and the pixel's centre disagree.
HULL_REPROJECTION_IOU_MIN = 0.97

# --- Round-off and pixels ------------------------------------------------------------

#: Float64 round-off of a short computation on values of order one (metres, radians, unit
#: vectors, matrix entries; or relative): 1e-16 per operation, so 1e-12 leaves room for
#: thousands of operations and still catches any real error.
ROUND_OFF = 1e-12
#: The same for pixel coordinates (hundreds of pixels, through a 3x4 projection and a
#: division): two computations of one projection agree far better than this.
PIXEL_ROUND_OFF_PX = 1e-9
#: Half the diagonal of a pixel: a point lies within this of its pixel's centre, so a
#: pixel whose centre is inside a disc of radius R lies inside the disc of R + this.
HALF_PIXEL_DIAGONAL_PX = 0.5 * 2.0 ** 0.5
