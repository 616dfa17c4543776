"""The texture atlas on the mug: time, atlas, and colour error in held-out views.

A simulated scan of the mug (three rings of 16 views and one from above, 320 x 240 px,
the tests' rig) painted with :func:`~sfs_ros.core.simulation.objects.fine_color_at` (a
3-D pattern of 5 mm period), unshaded, four views held out. For each grid the mesh is
reconstructed with vertex colours, then textured (:func:`texture_reconstruction`,
timed), and both are drawn unshaded into the held-out views: error = mean absolute
difference (grey levels) from the held-out images over the pixels the mesh and the true
mug both cover, eroded by 2 px.

Run: ``python -m bench.bench_texture``.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from sfs_ros.core.exchange.inputs import load_views
from sfs_ros.core.exchange.session import write_session
from sfs_ros.core.geometry.rig import RigCalibration, rig_camera
from sfs_ros.core.pipeline import ReconstructionParams, reconstruct
from sfs_ros.core.render import rasterize_silhouette, render_image
from sfs_ros.core.simulation.objects import fine_color_at, make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box, simulate_scan
from sfs_ros.core.texture import texture_reconstruction

RIG = RigCalibration(width=320, height=240, projection="pinhole", fx=700.0, fy=700.0,
                     camera_distance_m=0.6, aim_point_m=(0.0, 0.0, 0.04))
PLAN = ring_plan([15.0, 40.0, 65.0], 16, top_view=True)
HELD_OUT = (3, 21, 38, 48)
#: Grids: 40 and 64 voxels a side, and None (the pixel footprint, 0.84 mm voxels).
RESOLUTIONS = (40, 64, None)


def held_out_error(mug, captures, vertices, faces, **colouring) -> float:
    """Mean absolute colour error (grey levels) in the held-out views (module docstring)."""
    errors = []
    for i in HELD_OUT:
        camera = rig_camera(captures[i].theta_rad, captures[i].phi_rad, RIG)
        drawn = render_image(vertices, faces, camera, ambient=1.0, noise_sigma=0.0, **colouring)
        both = (rasterize_silhouette(vertices, faces, camera)
                & rasterize_silhouette(mug.mesh.vertices, mug.mesh.faces, camera))
        both = cv2.erode(both.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        errors.append(np.abs(drawn.astype(float) - captures[i].image)[both].mean())
    return float(np.mean(errors))


def main() -> None:
    mug = make_object("mug")
    captures = simulate_scan(mug, RIG, PLAN, seed=1, surface_color=fine_color_at, ambient=1.0)
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_session(Path(tmp) / "session", [(c.name, c.image) for c in captures],
                               [(c.theta_rad, c.phi_rad) for c in captures], RIG,
                               bounds_m=carving_box(mug))
        view_set = load_views(folder)
        for resolution in RESOLUTIONS:
            params = ReconstructionParams(resolution=resolution, colour=True,
                                          holdout=tuple(captures[i].name for i in HELD_OUT))
            start = time.perf_counter()
            result = reconstruct(view_set, params)
            mesh_s = time.perf_counter() - start
            start = time.perf_counter()
            textured = texture_reconstruction(view_set, result)
            texture_s = time.perf_counter() - start
            stats = textured.stats
            print(f"grid {resolution or 'footprint'}: {stats['faces']} faces; mesh {mesh_s:.2f} s "
                  f"(colour {result.report['timings_s'].get('colour', 0):.2f} s), texture "
                  f"{texture_s:.2f} s {({k: round(v, 2) for k, v in stats['seconds'].items()})}; "
                  f"{stats['charts']} charts, {stats['seam_edges']} seam edges, atlas "
                  f"{stats['atlas_size']} used {stats['atlas_use']:.2f}; held-out error: "
                  f"texture {held_out_error(mug, captures, textured.vertices, textured.faces, pixel_colors=textured.colour_at):.1f}, "  # noqa: E501
                  f"vertex colours {held_out_error(mug, captures, result.vertices, result.faces, vertex_colors=result.vertex_colors):.1f}")  # noqa: E501


if __name__ == "__main__":
    main()
