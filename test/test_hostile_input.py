"""Hostile input, as a careless or hostile user gives it: every case ends with exit 0 or 2,
one line on stderr, no traceback, within 4 GB of memory; nothing outside the input is
opened and no input file is written.

Each class of the threat list has its generators: document structure (YAML aliases,
deep nesting), numbers and types, paths and links, image headers (decode bombs), output
clashes and options. They run over every input format (session folder, Middlebury
``*_par.txt``, NeRF ``transforms.json``), all in one driver process
(``fuzz_driver.py``), so that its peak memory belongs to these cases alone.
"""

import contextlib
import json
import os
import re
import shutil
import sqlite3
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import pytest
import yaml
from test_hostile_round_three import bomb_bags, zstd_bomb

from sfs_ros.core.exchange.limits import MAX_BAG_RECORD_BYTES
from sfs_ros.core.exchange.pose_export import write_colmap, write_nerf_transforms
from sfs_ros.core.exchange.session import read_session, write_session
from sfs_ros.core.geometry.rig import RigCalibration
from sfs_ros.core.simulation.objects import make_object
from sfs_ros.core.simulation.plan import ring_plan
from sfs_ros.core.simulation.synthetic import carving_box, simulate_scan

from test_bag import (
    PARAMETERS_TOPIC,
    document,
    mask_messages,
    parameters_message,
    sphere_views,
    write_bag,
)

HERE = Path(__file__).resolve().parent
#: The acceptance bound on the memory of the whole run, MiB (the issue's 4 GB); the
#: driver's own start-up (numba, OpenCV, SciPy) takes about 300 MiB of it.
MAX_PEAK_MIB = 4096
#: Small and fast: every valid case reconstructs in well under a second.
RIG = RigCalibration(width=96, height=72, projection="pinhole", fx=160.0, fy=160.0,
                     camera_distance_m=0.5, aim_point_m=(0.0, 0.0, 0.05))
FAST = ["-r", "24", "-q"]
#: Expected outcomes: refused with exit 2, or a mesh with exit 0.
REFUSED, OK = "refused", "ok"
#: What a message must never name instead of the file it is about: an atomic writer's
#: temporary, or the folders where a bag and a parameters file are unpacked for reading.
TEMPORARY = re.compile(r"\.[0-9a-f]{8}\.tmp\b|sfs_bag_|sfs_params_")


def png_header(width: int, height: int, *, bit_depth: int = 8, colour_type: int = 2) -> bytes:
    """A PNG signature and IHDR chunk declaring ``width`` x ``height`` (no pixel data)."""
    body = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0)
    chunk = b"IHDR" + body
    return (b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(body)) + chunk
            + struct.pack(">I", zlib.crc32(chunk)))


def alias_bomb(levels: int = 9) -> str:
    """YAML whose aliases expand to 10**levels items (a few hundred bytes)."""
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    for n in range(1, levels):
        lines.append(f"a{n}: &a{n} [" + ", ".join([f"*a{n - 1}"] * 10) + "]")
    return "\n".join(lines)


class Cases:
    """Builds input folders and the argument lists that run on them."""

    def __init__(self, root: Path, base: Path):
        self.root, self.base, self.cases, self.n = root, base, [], 0

    def folder(self) -> Path:
        self.n += 1
        return self.root / f"case{self.n:03d}"

    def session(self) -> Path:
        folder = self.folder() / "session"
        shutil.copytree(self.base, folder, symlinks=True)
        return folder

    def add(self, case_id: str, argv, tool: str = "reconstruct", *, expect: str = REFUSED):
        """One case; ``expect`` is :data:`REFUSED`, :data:`OK`, or the name of a view that
        must be reported rejected if the tool does not refuse the input as a whole."""
        argv = [str(a) for a in argv]
        if tool == "reconstruct" and "-o" not in argv:
            out = self.root / "out" / f"{len(self.cases):03d}"
            argv += ["-o", str(out / "mesh.ply"), *FAST]
        self.cases.append({"id": case_id, "tool": tool, "argv": argv, "expect": expect})

    def session_yaml(self, case_id: str, edit) -> None:
        folder = self.session()
        path = folder / "session.yaml"
        if callable(edit):
            data = yaml.safe_load(path.read_text())
            edit(data)
            path.write_text(yaml.safe_dump(data))
        else:
            path.write_text(edit)
        self.add(case_id, [folder])


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    """A 13-view session of a 5 cm sphere on a 96 x 72 camera."""
    sphere = make_object("sphere")
    captures = simulate_scan(sphere, RIG, ring_plan([30.0], 12, top_view=True), seed=3)
    folder = tmp_path_factory.mktemp("base") / "session"
    write_session(folder, [(c.name, c.image) for c in captures],
                  [(c.theta_rad, c.phi_rad) for c in captures], RIG,
                  bounds_m=carving_box(sphere))
    return folder


def middlebury(folder: Path, session: Path) -> Path:
    """The session's views as a Middlebury ``*_par.txt`` beside copies of its images."""
    folder.mkdir(parents=True)
    views = read_session(session).views
    lines = [str(len(views))]
    for v in views:
        shutil.copy(v.image_path, folder / v.name)
        c = v.camera
        lines.append(" ".join([v.name] + [repr(float(x)) for x in (*c.K.ravel(), *c.R.ravel(), *c.t)]))
    (folder / "toy_par.txt").write_text("\n".join(lines) + "\n")
    return folder / "toy_par.txt"


def _sql(bag: Path, *statements) -> None:
    """Run SQL ``statements`` (each a string or (string, parameters)) on ``bag``'s .db3."""
    with contextlib.closing(sqlite3.connect(bag / "bag.db3")) as db, db:
        for statement in statements:
            db.execute(*((statement,) if isinstance(statement, str) else statement))


def huge_row(bag: Path) -> None:
    """The bag's fifth message replaced by one larger than a bag record may be."""
    _sql(bag, ("UPDATE messages SET data = zeroblob(?) WHERE id = 5",
               (MAX_BAG_RECORD_BYTES + 1,)))


def corrupt_row(bag: Path) -> None:
    """The bag's sixth message (a mask) cut to 20 bytes: not a valid message."""
    _sql(bag, "UPDATE messages SET data = substr(data, 1, 20) WHERE id = 6")


def foreign_type(bag: Path) -> None:
    """A topic whose recorded type names a module to run (issue 29, class 1)."""
    _sql(bag, "INSERT INTO topics (name, type, serialization_format, offered_qos_profiles, "
              "type_description_hash) VALUES ('/cell/capture/other', 'venv/__main__/X', 'cdr', "
              "'', '')",
         "INSERT INTO messages (topic_id, timestamp, data) SELECT id, 1, x'00000000' "
         "FROM topics WHERE name = '/cell/capture/other'")


def colmap(folder: Path, session: Path) -> Path:
    """The session's views as a COLMAP text model in ``folder``, its images in ``images/``."""
    write_colmap(read_session(session), folder)
    shutil.copytree(session / "images", folder / "images")
    return folder


def edit_line(path: Path, index: int, edit) -> None:
    """Replace the fields of the ``index``-th line of ``path`` that is not a comment nor
    blank by ``edit(fields)`` (a list of strings)."""
    lines = path.read_text().splitlines()
    data = [n for n, line in enumerate(lines) if line.strip() and not line.startswith("#")]
    lines[data[index]] = " ".join(edit(lines[data[index]].split()))
    path.write_text("\n".join(lines) + "\n")


def colmap_cases(c: "Cases", base: Path, secret: Path) -> None:
    """COLMAP text models: numbers, structure, names and links in ``cameras.txt`` and
    ``images.txt`` (the first image, ``view_000.png``, is the one edited)."""
    def model(case_id: str, name: str, edit, *, expect: str = REFUSED, index: int = 0):
        folder = colmap(c.folder() / "model", base)
        edit_line(folder / name, index, edit)
        c.add(case_id, [folder], expect=expect)

    c.add("colmap: valid", [colmap(c.folder() / "model", base)], expect=OK)
    for field, value in [(2, "1e9"), (2, "0"), (2, "95.5"), (3, "-72"), (4, "1e300"),
                         (4, "1e-300"), (4, "0"), (4, "-160"), (4, "nan"), (4, "inf"),
                         (4, "abc"), (6, "1e308"), (7, "-1e308")]:
        model(f"colmap: cameras.txt field {field} = {value}", "cameras.txt",
              lambda f, i=field, v=value: f[:i] + [v] + f[i + 1:])
    for case, edit in {"model FISHEYE": lambda f: f[:1] + ["SIMPLE_RADIAL_FISHEYE"] + f[2:],
                       "one parameter too many": lambda f: f + ["1"],
                       "no parameters": lambda f: f[:4],
                       "camera id twice": lambda f: f + ["\n" + " ".join(f)],
                       "OPENCV k1 1e300": lambda f: [f[0], "OPENCV", *f[2:], "1e300", "0", "0",
                                                     "0"]}.items():
        model(f"colmap: cameras.txt {case}", "cameras.txt", edit)
    rejected = "view_000.png"
    for field, value, expect in [(1, "0", rejected), (1, "1e308", rejected),
                                 (2, "1e-300", rejected), (5, "1e308", REFUSED),
                                 (5, "1e300", REFUSED), (7, "1e-300", REFUSED),
                                 (1, "nan", REFUSED), (5, "abc", REFUSED)]:
        model(f"colmap: images.txt field {field} = {value}", "images.txt",
              lambda f, i=field, v=value: f[:i] + [v] + f[i + 1:], expect=expect)
    for case, edit in {"unknown camera": lambda f: f[:8] + ["99"] + f[9:],
                       "too few fields": lambda f: f[:6],
                       "image listed twice": lambda f: f + ["\n" + " ".join(f)],
                       "image missing": lambda f: f[:9] + ["missing.png"],
                       "image name ../../x": lambda f: f[:9] + ["../../secret/outside.png"],
                       "absolute image name": lambda f: f[:9] + [str(secret / "outside.png")],
                       "points line of garbage": lambda f: f + ["\n1 2 x 4 5"],
                       "a name with spaces and escapes": lambda f: f[:9] + ["a \x1b[31m.png"],
                       }.items():
        model(f"colmap: images.txt {case}", "images.txt", edit)
    for name, text in [("cameras.txt", ""), ("images.txt", "# only a comment\n"),
                       ("cameras.txt", "\x00\x01\x02" * 100), ("images.txt", "9" * 100000)]:
        folder = colmap(c.folder() / "model", base)
        (folder / name).write_text(text)
        c.add(f"colmap: {name} is {text[:12]!r}", [folder])
    folder = colmap(c.folder() / "model", base)
    (folder / "images" / "view_000.png").write_bytes(png_header(50000, 50000))
    c.add("colmap: image a 50000^2 PNG header", [folder], expect=rejected)
    folder = colmap(c.folder() / "model", base)
    (folder / "images" / "view_000.png").unlink()
    os.symlink(secret / "outside.png", folder / "images" / "view_000.png")
    c.add("colmap: an image is a link outside", [folder])


def build_cases(root: Path, base: Path, secret: Path) -> Cases:
    c = Cases(root, base)
    outside_png = secret / "outside.png"

    # ---- a valid input of each format reconstructs (exit 0)
    c.add("session: valid", [c.session()], expect=OK)
    par = middlebury(c.folder(), base)
    c.add("middlebury: valid", [par], expect=OK)
    nerf_session = c.session()
    nerf = write_nerf_transforms(read_session(nerf_session), nerf_session / "transforms.json")
    c.add("nerf: valid", [nerf], expect=OK)

    # ---- YAML and JSON structure
    c.session_yaml("yaml: alias bomb under rig", "format: sfs_ros-session\nversion: 1\nrig:\n"
                   + "\n".join("  " + line for line in alias_bomb().splitlines()))
    c.session_yaml("yaml: alias of a valid value", "format: sfs_ros-session\nversion: 1\n"
                   "rig: &r {width: 96, height: 72}\nsegmentation: *r\n")
    c.session_yaml("yaml: deep nesting", "format: sfs_ros-session\nversion: 1\nrig: "
                   + "[" * 5000 + "]" * 5000 + "\n")
    c.session_yaml("yaml: not a mapping", "- just\n- a list\n")
    c.session_yaml("yaml: binary", "\x00\x01\x02 not yaml")
    c.session_yaml("yaml: unknown key with escape codes", lambda d: d.update({"\x1b[31mred": 1}))
    for n, text in enumerate(["[" * 100000 + "]" * 100000, '{"frames": "no"}', "[]",
                              '{"frames": [1, 2]}', '{"frames": [{"file_path": 5}]}', "{"]):
        folder = c.folder()
        folder.mkdir()
        (folder / "transforms.json").write_text(text)
        c.add(f"json: structure {n}", [folder / "transforms.json"])

    # ---- numbers and types
    for field, value in [("width", "200"), ("width", 200.7), ("width", True), ("width", 0),
                         ("height", 10**12), ("fx", float("inf")), ("fx", 1e300), ("fx", 1e-300),
                         ("fx", "abc"), ("camera_distance_m", 1e300),
                         ("camera_distance_m", 1e-300), ("camera_distance_m", float("nan")),
                         ("aim_point_m", "abc"), ("aim_point_m", [1, 2]),
                         ("theta_zero_rad", 1e308), ("projection", ["pinhole"]),
                         ("convention", {"a": 1})]:
        c.session_yaml(f"rig {field}={value!r}",
                       lambda d, f=field, v=value: d["rig"].update({f: v}))
    for key, value in [("version", True), ("version", 1.0), ("version", "1"), ("rig", [1, 2]),
                       ("bounds_m", "box"), ("bounds_m", [[0, 0, 0], [1e400, 1, 1]]),
                       ("segmentation", "fast"), ("segmentation", {"threshold": "abc"}),
                       ("segmentation", {"threshold": float("nan")}),
                       ("segmentation", {"open_px": 1e9}), ("segmentation", {"open_px": 10**9}),
                       ("segmentation", {"dilate_px": 2.5})]:
        c.session_yaml(f"session {key}={value!r}", lambda d, k=key, v=value: d.update({k: v}))
    for n, (row, expect) in enumerate([("view_000.png,1e400,0.5", "view_000.png"),
                                       ("view_000.png,nan,nan", "view_000.png"),
                                       ("view_000.png,1e308,0.5", "view_000.png"),
                                       ("view_000.png,0.1,-1e300", "view_000.png"),
                                       ("view_000.png,0.1", REFUSED),
                                       ("view_000.png,0.1,0.2,0.3", REFUSED),
                                       ("view_000.png," + "9" * 5000 + ",0.1", "view_000.png"),
                                       ("\x00\x00", REFUSED)]):
        folder = c.session()
        table = (folder / "views.csv").read_text().splitlines()
        table[1] = row
        (folder / "views.csv").write_text("\n".join(table) + "\n")
        c.add(f"views.csv row {n}", [folder], expect=expect)
    for n, edit in enumerate([lambda f: f.__setitem__(1, "1e400"), lambda f: f.__setitem__(1, "x"),
                              lambda f: f.__setitem__(9, "0"), lambda f: f.__setitem__(10, "5"),
                              lambda f: f.append("1")]):
        folder = c.folder()
        par = middlebury(folder, base)
        lines = par.read_text().splitlines()
        fields = lines[1].split()
        edit(fields)
        lines[1] = " ".join(fields)
        par.write_text("\n".join(lines) + "\n")
        c.add(f"middlebury numbers {n}", [par])
    for n, count in enumerate(["²", "9" * 5000, "-1", "0"]):
        folder = c.folder()
        par = middlebury(folder, base)
        lines = par.read_text().splitlines()
        lines[0] = count
        par.write_text("\n".join(lines) + "\n")
        c.add(f"middlebury count {n}", [par])
    for key, value in ([("fl_x", "abc"), ("fl_x", 1e300), ("w", 1e300),
                                      ("w", -5), ("h", 0.4), ("transform_matrix", "I"),
                                      ("transform_matrix", [[1e308] * 4] * 4), ("k4", 0.1),
                                      ("k1", 1e300)]):
        folder = c.session()
        path = write_nerf_transforms(read_session(folder), folder / "transforms.json")
        data = json.loads(path.read_text())
        data["frames"][0][key] = value
        path.write_text(json.dumps(data))
        # One frame's camera is absurd: refused, or that view is named as rejected.
        c.add(f"nerf {key}={value!r}", [path], expect=data["frames"][0]["file_path"])

    # ---- paths and links: nothing outside the input is read
    folder = c.session()
    shutil.rmtree(folder / "images")
    os.symlink(secret, folder / "images")
    c.add("session: images/ is a link outside", [folder])
    folder = c.session()
    (folder / "images" / "view_000.png").unlink()
    os.symlink(outside_png, folder / "images" / "view_000.png")
    c.add("session: an image is a link outside", [folder])
    for name in ("../../secret/outside.png", str(outside_png), "images/../../x.png"):
        folder = c.session()
        table = (folder / "views.csv").read_text().splitlines()
        table[1] = f"{name},0.1,0.5"
        (folder / "views.csv").write_text("\n".join(table) + "\n")
        c.add(f"session: image name {name!r}", [folder])
    for name in (str(outside_png), "../secret/outside.png", "../../secret/outside.png"):
        folder = c.folder()
        par = middlebury(folder, base)
        par.write_text(par.read_text().replace("view_000.png", name, 1))
        c.add(f"middlebury: image name {name!r}", [par])
    for file_path in (str(outside_png), "../secret/outside.png", "../../secret/outside"):
        folder = c.session()
        path = write_nerf_transforms(read_session(folder), folder / "transforms.json")
        data = json.loads(path.read_text())
        data["frames"][0]["file_path"] = file_path
        path.write_text(json.dumps(data))
        c.add(f"nerf: file_path {file_path!r}", [path])
    folder = c.session()
    path = write_nerf_transforms(read_session(folder), folder / "transforms.json")
    os.symlink(outside_png, folder / "images" / "linked.png")
    data = json.loads(path.read_text())
    data["frames"][0]["file_path"] = "images/linked.png"
    path.write_text(json.dumps(data))
    c.add("nerf: file_path is a link outside", [path])

    # ---- image headers: refused before decoding
    for data, what in ([(png_header(50000, 50000), "50000^2 PNG header"),
                                      (png_header(20000, 20000, bit_depth=16, colour_type=6),
                                       "20000^2 16-bit RGBA header"),
                                      (png_header(96, 72), "right size, no pixels"),
                                      (b"", "empty file"), (b"GIF89a" + b"\x00" * 20, "a GIF"),
                                      (b"not an image at all", "text")]):
        for fmt in ("session", "middlebury"):
            folder = c.session() if fmt == "session" else c.folder()
            target = folder / "images" / "view_000.png" if fmt == "session" else None
            if fmt == "middlebury":
                par = middlebury(folder, base)
                target = folder / "view_000.png"
            target.write_bytes(data)
            # A session decodes images view by view: a bad one is a rejected view.
            c.add(f"{fmt}: image {what}", [folder if fmt == "session" else par],
                  expect="view_000.png" if fmt == "session" else REFUSED)
    folder = c.session()
    with open(folder / "images" / "view_000.png", "r+b") as f:
        f.truncate(3 << 30)  # sparse: 3 GiB of nothing
    c.add("session: sparse 3 GiB image", [folder], expect="view_000.png")
    folder = c.session()
    image = cv2.imread(str(folder / "images" / "view_001.png"))
    cv2.imwrite(str(folder / "images" / "view_001.png"), cv2.resize(image, (200, 150)))
    c.add("session: an image of the wrong size", [folder], expect="view_001.png")

    # ---- bags: recorded parameters of the wrong shape, cut and foreign files
    def bag(case_id: str, edit=None, *, expect: str = REFUSED, cut=None, extra=None,
            storage: str = "mcap") -> None:
        folder = c.folder() / "bag"
        doc = document()
        if edit is not None:
            edit(doc)
        write_bag(folder, [(PARAMETERS_TOPIC, parameters_message(doc)),
                           *mask_messages(sphere_views())], storage=storage)
        if cut is not None:
            data = folder / ("bag.mcap" if storage == "mcap" else "bag.db3")
            data.write_bytes(data.read_bytes()[:cut(data.stat().st_size)])
            (folder / "metadata.yaml").unlink()
        if extra is not None:
            extra(folder)
        c.add(case_id, [folder], expect=expect)

    bag("bag: valid", expect=OK)
    bag("bag: nodes is a list", lambda d: d.update(nodes=[1, 2]))
    bag("bag: scan parameters a string", lambda d: d["nodes"].update(scan="x"))
    bag("bag: session missing", lambda d: d.pop("session"))
    bag("bag: rig a number", lambda d: d["session"].update(rig=5))
    bag("bag: resolution a string", lambda d: d["reconstruction"].update(resolution="big"))
    bag("bag: cut inside its summary", cut=lambda size: size - 9, expect=OK)
    bag("bag: cut in half", cut=lambda size: size // 2, expect=OK)
    bag("bag: cut inside its header", cut=lambda size: 5)
    # The MCAP records are whole: read from them, the metadata ignored (memory bounded).
    bag("bag: metadata.yaml an alias bomb", expect=OK,
        extra=lambda f: (f / "metadata.yaml").write_text(alias_bomb()))
    bag("bag: mcap file replaced by text",
        extra=lambda f: (f / "bag.mcap").write_text("not a bag"))
    # A chunk of 98 KB of zstd expanding to 3 GiB, declaring that or a few bytes (issue 29).
    for case, folder in bomb_bags(c.folder(), zstd_bomb()).items():
        c.add(f"bag: zstd bomb chunk {case}", [folder])
        c.add(f"sfs-export of a bag: zstd bomb chunk {case}",
              [folder, "--colmap", root / "out" / "bomb_export"], tool="export")
    # The same in rosbag2's other storage, SQLite 3 (.db3).
    bag("bag sqlite3: valid", expect=OK, storage="sqlite3")
    bag("bag sqlite3: nodes is a list", lambda d: d.update(nodes=[1, 2]), storage="sqlite3")
    bag("bag sqlite3: rig a number", lambda d: d["session"].update(rig=5), storage="sqlite3")
    bag("bag sqlite3: cut in half", cut=lambda size: size // 2, storage="sqlite3")
    # (rosbag2's SQLite reader needs metadata.yaml: a clear refusal.)
    bag("bag sqlite3: metadata.yaml an alias bomb", storage="sqlite3",
        extra=lambda f: (f / "metadata.yaml").write_text(alias_bomb()))
    bag("bag sqlite3: db3 file replaced by text", storage="sqlite3",
        extra=lambda f: (f / "bag.db3").write_text("not a bag"))
    bag("bag sqlite3: a message row over the limit", storage="sqlite3", extra=huge_row)
    bag("bag sqlite3: a corrupt message", expect=OK, storage="sqlite3", extra=corrupt_row)
    bag("bag sqlite3: a topic typed venv/__main__/X", expect=OK, storage="sqlite3",
        extra=foreign_type)
    bag("bag sqlite3: metadata.yaml without its duration", storage="sqlite3",
        extra=lambda f: (f / "metadata.yaml").write_text(
            (f / "metadata.yaml").read_text().replace("duration:", "lasted:")))
    bag("bag sqlite3: no messages table", storage="sqlite3",
        extra=lambda f: _sql(f, "DROP TABLE messages"))
    # A COLMAP model whose images/ is a link outside (as a session's is refused).
    model = c.folder() / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "cameras.txt").write_text("1 PINHOLE 96 72 160 160 48 36\n")
    (model / "images.txt").write_text("1 1 0 0 0 0 0 0.5 1 outside.png\n\n")
    os.symlink(secret, model / "images")
    c.add("colmap: images/ is a link outside", [model])

    colmap_cases(c, base, secret)

    # ---- output clashes: no input file is ever written, no output overwrites another
    out = root / "clash"
    folder = c.session()
    c.add("--html is the mesh", [folder, "-o", out / "m.ply", "--html", out / "m.ply", *FAST])
    folder = c.session()
    c.add("--contact-sheet is views.csv", [folder, "-o", out / "n.ply", "--contact-sheet",
                                           folder / "views.csv", *FAST])
    folder = c.session()
    c.add("--preview is an input image", [folder, "-o", out / "p.ply", "--preview",
                                          folder / "images" / "view_002.png", *FAST])
    folder = c.session()
    c.add("-o is the report's place of another output",
          [folder, "-o", out / "q.ply", "--html", out / "q.report.json", *FAST])
    folder = c.session()
    c.add("sfs-export into its own input", [folder, "--session", folder], tool="export")
    folder = c.session()
    c.add("sfs-export into its input's images", [folder, "--colmap", folder / "images"],
          tool="export")

    # ---- options
    for n, options in enumerate([["-r", "0"], ["-r", "-5"], ["-r", "100000"],
                                 ["--max-misses", "100"], ["--voxel-size", "nan"],
                                 ["--voxel-size", "1e-9"], ["--voxel-size", "1e3"],
                                 ["--voxel-size", "inf"], ["--block", "0"],
                                 ["--bounds", "-1e4", "-1e4", "-1e4", "1e4", "1e4", "1e4"],
                                 ["--bounds", "5", "5", "5", "6", "6", "6"],
                                 ["--bounds", "1", "1", "1", "0", "0", "0"],
                                 ["--holdout", "999"], ["--threshold", "7"]]):
        c.add(f"options {' '.join(options)}", [c.session(), "-o", root / "out" / f"o{n}.ply",
                                               "-q", *options])
    return c


def rejected_views(case: dict) -> set[str]:
    """The views a case that ended with exit 0 reports rejected: in the mesh's report, or
    in ``calibration_report.yaml`` (``sfs-calibrate``)."""
    out = Path(case["argv"][case["argv"].index("-o") + 1])
    if case["tool"] == "calibrate":
        return set(yaml.safe_load((out / "calibration_report.yaml").read_text())["rejected"])
    report = json.loads(out.with_name(out.stem + ".report.json").read_text())
    return {v["view"] for v in report["views"]["rejected"]}


def failures(cases: list[dict], results: list[dict]) -> list[str]:
    """What each case did wrong against the rules of the module docstring and its
    ``expect``: one line per failure."""
    found = []
    for case, r in zip(cases, results):
        lines = r["stderr"].splitlines()
        expect = case["expect"]
        if r["traceback"]:
            found.append(f"{r['id']}: traceback\n{r['traceback']}")
            continue
        if "Traceback" in r["stderr"] or "\x1b" in r["stderr"]:
            found.append(f"{r['id']}: raw traceback or escape code on stderr")
        if r["warnings"]:
            # A NumPy RuntimeWarning (overflow, invalid value) is a number not checked.
            found.append(f"{r['id']}: warnings {r['warnings'][:3]}")
        if TEMPORARY.search(r["stderr"]):
            found.append(f"{r['id']}: names a temporary file: {r['stderr'][:300]!r}")
        if r["status"] == 2 and (len(lines) != 1 or ": error: " not in lines[0]):
            # One line saying what was wrong; "internal error" is a bug, not an answer.
            found.append(f"{r['id']}: {len(lines)} lines on stderr: {r['stderr'][:500]!r}")
        if r["status"] == 0 and len(lines) > 1:
            # At most one warning (e.g. "the bag was cut; N whole messages read").
            found.append(f"{r['id']}: exit 0 with stderr {r['stderr'][:300]!r}")
        if expect == REFUSED and r["status"] != 2:
            found.append(f"{r['id']}: expected a refusal (exit 2), got exit {r['status']}")
        elif expect == OK and r["status"] != 0:
            found.append(f"{r['id']}: expected a mesh, got exit {r['status']}: {r['stderr']}")
        elif expect not in (REFUSED, OK):
            if r["status"] == 0:
                if expect not in rejected_views(case):
                    found.append(f"{r['id']}: exit 0 without naming {expect} as rejected")
            elif r["status"] != 2:
                found.append(f"{r['id']}: exit {r['status']}")
        if r["opened"]:
            found.append(f"{r['id']}: {r['opened']}")
    return found


def test_every_hostile_case_ends_cleanly_and_stays_inside_its_input(base, tmp_path):
    secret = tmp_path / "secret"
    secret.mkdir()
    shutil.copy(base / "images" / "view_000.png", secret / "outside.png")
    (secret / "outside").mkdir()
    cases = build_cases(tmp_path / "cases", base, secret)
    inputs = sorted(str(p) for p in (tmp_path / "cases").glob("case*"))
    before = {p: p.read_bytes() for folder in inputs for p in Path(folder).rglob("*")
              if p.is_file() and not p.is_symlink() and p.stat().st_size < 1 << 20}
    spec = tmp_path / "cases.json"
    spec.write_text(json.dumps({"watched": [str(secret)], "inputs": inputs,
                                "cases": cases.cases}))
    results_path = tmp_path / "results.json"
    done = subprocess.run([sys.executable, str(HERE / "fuzz_driver.py"), str(spec),
                           str(results_path)], cwd=HERE.parent, capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(HERE.parent)), timeout=1800)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(results_path.read_text())

    found = failures(cases.cases, report["results"])
    assert not found, f"{len(found)} of {len(cases.cases)} cases:\n" + "\n".join(found)
    assert report["peak_rss_mib"] < MAX_PEAK_MIB
    changed = [str(p) for p, data in before.items() if not p.is_file() or p.read_bytes() != data]
    assert not changed, f"input files written: {changed[:5]}"
