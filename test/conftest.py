"""Shared fixtures: a simulated scan of a known object, written as a session folder."""

import pytest

from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.simulation.synthetic import carving_box, simulate_scan

#: Small pinhole camera so the end-to-end tests stay fast: 320 x 240 px, 0.6 m away.
TEST_RIG = RigCalibration(width=320, height=240, projection="pinhole", fx=700.0, fy=700.0,
                          camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
#: Three rings of 16 views plus one from above.
TEST_PLAN = ring_plan([15.0, 40.0, 65.0], 16, top_view=True)


@pytest.fixture(scope="session")
def mug():
    return make_object("mug")


@pytest.fixture(scope="session")
def mug_captures(mug):
    return simulate_scan(mug, TEST_RIG, TEST_PLAN, seed=1)


def write_mug_session(folder, mug, captures):
    """Write the scan as a session folder with a carving box 1 cm around the mug."""
    write_session(folder, [(c.name, c.image) for c in captures],
                  [(c.theta_rad, c.phi_rad) for c in captures], TEST_RIG,
                  bounds_m=carving_box(mug))
    return folder


@pytest.fixture()
def mug_session(tmp_path, mug, mug_captures):
    """A fresh session folder of the mug scan (tests may damage it)."""
    return write_mug_session(tmp_path / "mug_session", mug, mug_captures)


@pytest.fixture(scope="session")
def mug_views(tmp_path_factory, mug, mug_captures):
    """The mug scan loaded as a ViewSet (shared: do not modify its files)."""
    return load_views(write_mug_session(tmp_path_factory.mktemp("scan") / "session", mug,
                                       mug_captures))
