"""The scan node's progress on disk (sfs_ros.cell_logic.scan_progress) and a restarted sequence
taking the scan up from it (ScanSequence.restore), with the simulated cell of
test_scan_sequence: no processes.

A node killed outright is a :class:`Killed` (not an ``Exception``, so the sequence cannot
catch it) raised from its ``send`` port: the run ends there, as the process would.
"""

import json

import numpy as np
import pytest

from sfs_ros.cell_logic.capture_ledger import EncoderReading
from sfs_ros.cell_logic.scan_progress import PROGRESS_FILE, SavedCapture, SavedScan, ScanProgress
from sfs_ros.cell_logic.scan_sequence import ScanSequence

from test_scan_sequence import SETTINGS, VIEWS, FakeCell


class Killed(BaseException):
    """The process died (SIGKILL)."""


class PersistentCell(FakeCell):
    """The simulated cell with the scan's progress kept in ``folder``; killed at the
    ``kill_at``-th send; its clock starts at ``start_s`` (a restarted process's clock has
    gone on: stamps never repeat)."""

    def __init__(self, folder, kill_at=None, start_s=0.0):
        super().__init__()
        self.t = start_s
        self.kill_at = kill_at
        self.seq = ScanSequence(VIEWS, self, SETTINGS, ScanProgress(folder, VIEWS))

    def encode_capture(self, capture) -> bytes:
        frame, stamp, r = capture
        return json.dumps([frame, stamp, [r.stamp, r.theta_rad, r.phi_rad]]).encode()

    def decode_capture(self, data: bytes):
        frame, stamp, (rstamp, theta, phi) = json.loads(data)
        return frame, tuple(stamp), EncoderReading(tuple(rstamp), theta, phi)

    def send(self, capture) -> None:
        if self.kill_at is not None and len(self.sent) + 1 == self.kill_at:
            raise Killed()
        super().send(capture)


def test_a_restarted_sequence_takes_the_scan_up_where_it_stood(tmp_path):
    first = PersistentCell(tmp_path, kill_at=3)
    with pytest.raises(Killed):
        first.run()                          # dies sending the third capture (kept already)
    first.seq.receipt(first.sent[0][1])      # the first one was receipted before

    second = PersistentCell(tmp_path, start_s=first.t + 60.0)
    go_on, message = second.seq.restore()
    assert go_on, message
    assert message == f"took up scan 1 (running): 3 of {len(VIEWS)} views captured; going on"
    status = second.seq.status().values
    assert (status["scan"], status["state"], status["captured"], status["receipted"]) == \
        (1, "running", 3, 1)
    second.seq.run()
    assert second.prepared == []                       # prepared once, before the death
    assert second.commands == [tuple(v) for v in VIEWS[3:]]   # only the views not captured
    assert second.views_sent() == [3, 4]
    second.seq.tick({"reconstruction"})      # a receiver not seen by this process: resend all
    assert sorted(second.views_sent()[2:]) == list(range(len(VIEWS)))
    before = {c[1] for c in first.sent}      # the two sent before the death ...
    assert before < {c[1] for c in second.sent[2:5]}      # ... go again with the third
    assert second.seq.status().values["state"] == "done"

    third = PersistentCell(tmp_path)                   # a restart after the end
    assert third.seq.restore() == (False, f"took up scan 1 (done): {len(VIEWS)} of "
                                          f"{len(VIEWS)} views captured")
    assert third.seq.status().values["receipted"] == 1


def test_the_capture_being_sent_when_killed_is_kept_with_its_encoder_reading(tmp_path):
    cell = PersistentCell(tmp_path, kill_at=1)
    with pytest.raises(Killed):
        cell.run()
    saved = ScanProgress(tmp_path, VIEWS).load()
    assert saved.scan == 1 and saved.state == "running" and saved.prepared
    (capture,) = saved.captures
    assert capture.view == 0 and not capture.receipted
    np.testing.assert_allclose((capture.theta_rad, capture.phi_rad), VIEWS[0], atol=1e-12)
    frame, stamp, _ = cell.decode_capture(ScanProgress(tmp_path, VIEWS).load_capture(capture))
    assert stamp == capture.stamp and frame == f"frame {stamp}"


def test_a_new_scan_forgets_the_captures_of_the_last_one(tmp_path):
    cell = PersistentCell(tmp_path)
    cell.run()
    files = sorted((tmp_path / "captures").iterdir())
    assert len(files) == len(VIEWS)
    # What a process killed in the middle of a write leaves (write_atomic's temporary files).
    (tmp_path / "captures" / f".{files[0].name}.0123abcd.tmp").write_bytes(b"half")
    (tmp_path / ".progress.json.89abcdef.tmp").write_bytes(b"{")
    cell.run()
    assert not (tmp_path / ".progress.json.89abcdef.tmp").exists()
    assert not set(files) & set((tmp_path / "captures").iterdir())
    assert len(list((tmp_path / "captures").iterdir())) == len(VIEWS)


def test_progress_of_another_plan_or_damaged_is_refused_with_the_reason(tmp_path):
    progress = ScanProgress(tmp_path, VIEWS)
    progress.save(SavedScan(2, "running", True, (SavedCapture(1, (5, 6), 0.1, 0.2, True),)))
    assert progress.load() == SavedScan(2, "running", True,
                                        (SavedCapture(1, (5, 6), 0.1, 0.2, True),))
    with pytest.raises(ValueError, match="another plan"):
        ScanProgress(tmp_path, VIEWS[:3]).load()
    path = tmp_path / PROGRESS_FILE
    path.write_text(path.read_text().replace('"view": 1', '"view": 9'))
    with pytest.raises(ValueError, match="view 9 is not an index of the plan's 5 views"):
        progress.load()
    path.write_text("{")
    with pytest.raises(ValueError, match="cannot be read"):
        progress.load()
    cell = PersistentCell(tmp_path)
    go_on, message = cell.seq.restore()
    assert not go_on and message.startswith("saved progress not taken up:")
    assert cell.seq.state == "idle"


def test_a_capture_file_lost_is_taken_again(tmp_path):
    first = PersistentCell(tmp_path, kill_at=3)
    with pytest.raises(Killed):
        first.run()
    lost = sorted((tmp_path / "captures").iterdir())[1]
    lost.unlink()
    second = PersistentCell(tmp_path, start_s=first.t + 60.0)
    go_on, message = second.seq.restore()
    assert go_on and "captures lost from the disk, to be taken again: view 2" in message
    second.seq.run()
    assert second.views_sent() == [1, 3, 4]
