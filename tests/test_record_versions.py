"""pipeline/records/upgrade.py: a record of each older version is verified by its own version's rules and read as
the current one, by the upgrades from its version on; committed records of each version alike."""

import json
from pathlib import Path

import pytest

from pipeline.records.schema import RECORD_VERSION
from pipeline.records.store import RecordError, RunRecord, file_digest, record_digest, run_dir
from pipeline.records.upgrade import (
    UPGRADES,
    inferred_version,
    record_version,
    upgraded,
    version_1_to_2,
    version_2_to_3,
)
from pipeline.records.verify import verified, verified_current
from pipeline.repo import REPO

HORIZON = 2
POSE = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 2.0]
SAMPLE = 12  # committed records of each version read as the current one


def _row(step: int, ties: bool) -> dict:
    scores = {"count": 8, "min": 0.1, "mean": 0.2, "max": 0.3, "std": 0.05} | ({"ties_at_max": 1} if ties else {})
    return {
        "step": step,
        "n_views": 3 + step,
        "status": "ok",
        "metrics": {"psnr": 20.0 + step, "lpips": None, "num_points": 100},
        "selected_pose": POSE,
        "selected_index": 4,
        "selected_score": 0.3,
        "refined": False,
        "candidate_scores": scores,
        "train": {"backbone": {"iters": 10.0, "steps": 10.0, "first_loss": 0.5, "last_loss": 0.1, "seconds": 1.0}},
        "seconds": {"train": 1.0, "eval": 0.5, "plan": 0.25},
    }


def _write(tmp_path: Path, version: int, method: str = "wd", scene: str = "room", versioned: bool = False) -> RunRecord:
    """A finished record as version ``version``'s code wrote it: run.json's keys of that version, the rows (without
    ``ties_at_max`` before version 3) and its digest; ``versioned``: with ``record_version`` (version 3 on)."""
    record = RunRecord(run_dir(tmp_path, scene, method, "argmax", "none", "cpu", 100))
    record.directory.mkdir(parents=True)
    config = {"budget": {"horizon": HORIZON}, "method": {"name": method}, "scene": {"name": scene}, "planner": {}}
    info = {"scene": scene, "method": method, "planner": "argmax", "ablation": "none", "budget": "cpu", "seed": 100}
    info |= {"config": config, "scene_source": "mesh", "field": "hashgrid", "device": "cpu", "torch_threads": 1}
    if version >= 2:
        info |= {"ground_truth": {"backend": "pyrender", "asset": "room/room.glb"}}
        info |= {"collision_free": False, "candidate_filters": True}
    if versioned:
        info["record_version"] = version
    info |= {"lpips_missing_reason": None, "status": "done", "timings": {"started": "t", "resumed": [], "ended": "t"}}
    steps = "".join(json.dumps(_row(step, ties=version >= 3)) + "\n" for step in range(HORIZON))
    record.steps_path.write_text(steps)
    if version == 2:
        info["steps_digest"] = file_digest(steps.encode())
    if version == 3:
        info["record_digest"] = record_digest(info, steps.encode())
    record.run_json.write_text(json.dumps(info))
    return record


@pytest.mark.parametrize(("version", "versioned"), [(1, False), (2, False), (3, False), (3, True)])
def test_a_record_of_each_version_verifies_and_reads_as_the_current_one(tmp_path, version, versioned):
    record = _write(tmp_path, version, versioned=versioned)
    info, rows = verified(record)
    assert info == json.loads(record.run_json.read_text())  # as recorded
    assert record_version(info) == version
    current, current_rows = verified_current(record)
    assert current["record_version"] == RECORD_VERSION
    assert current["candidate_filters"] is True  # WD filters its candidates
    assert current["collision_free"] is (version == 1)  # version 1: Room chose the collision-free sampler
    assert all(row["candidate_scores"]["ties_at_max"] == (1 if version >= 3 else None) for row in current_rows)
    assert all(current[key] == value for key, value in info.items())
    assert [row["metrics"] for row in current_rows] == [row["metrics"] for row in rows]  # values never change


def test_versions_are_told_apart_by_their_content_before_record_version():
    assert inferred_version({"seed": 1}) == 1  # no candidate_filters: before the digests
    assert inferred_version({"candidate_filters": True, "steps_digest": "sha256:0"}) == 2
    assert inferred_version({"candidate_filters": True, "record_digest": "sha256:0"}) == 3
    assert inferred_version({"candidate_filters": True}) == 3  # unfinished: versions 2 and 3 wrote the same keys
    assert record_version({"record_version": 3, "candidate_filters": True}) == 3  # written: it decides
    with pytest.raises(ValueError, match="holds keys only version 3 and later write"):  # unless its keys contradict it
        record_version({"record_version": 2, "record_digest": "sha256:0"})
    for bad in (0, RECORD_VERSION + 1, "3", True):
        with pytest.raises(ValueError, match="not a record version from 1 to"):
            record_version({"record_version": bad})
    assert sorted(UPGRADES) == list(range(1, RECORD_VERSION))  # one upgrade from each older version


def test_version_1_to_2_adds_what_version_1_chose_and_keeps_what_it_recorded():
    random = {"scene": "room_proxy", "config": {"method": {"name": "random"}, "planner": {"collision_free": None}}}
    info, rows = version_1_to_2(random, [])
    assert info["candidate_filters"] is False and info["collision_free"] is True  # Random skipped the filters
    assert "candidate_filters" not in random  # a copy
    config = {"method": {"name": "random"}, "planner": {"random_filters": True}}
    recorded = {"scene": "room", "collision_free": False, "config": config}
    assert version_1_to_2(recorded, [])[0] == recorded | {"candidate_filters": True}  # recorded: kept, not Room's
    assert version_1_to_2({"scene": "hotdog", "config": {}}, [])[0]["collision_free"] is False
    held = {"scene": "hotdog", "config": {}, "candidate_filters": False}
    assert version_1_to_2(held, [])[0]["candidate_filters"] is False  # a value the record holds is never changed


def test_version_2_to_3_marks_ties_not_counted_and_leaves_counted_ones():
    old, new = _row(0, ties=False), _row(1, ties=True)
    info, rows = version_2_to_3({"seed": 1}, [old, new, {"step": 2}])
    assert rows[0]["candidate_scores"]["ties_at_max"] is None and rows[1]["candidate_scores"]["ties_at_max"] == 1
    assert rows[2] == {"step": 2} and "ties_at_max" not in old["candidate_scores"]  # no scores: nothing; a copy
    assert info == {"seed": 1}


@pytest.mark.parametrize("version", [2, 3])
def test_a_record_of_a_version_that_takes_a_digest_is_refused_without_it(tmp_path, version):
    record = _write(tmp_path, version, versioned=version == 3)
    info = json.loads(record.run_json.read_text())
    del info["steps_digest" if version == 2 else "record_digest"]
    record.run_json.write_text(json.dumps(info))
    with pytest.raises(RecordError, match=r"run.json: no record_digest, though the version that wrote it"):
        verified(record)  # without steps_digest a version-2 record reads as version 3, which takes record_digest


def test_a_versioned_record_is_held_to_its_own_version(tmp_path):
    """A record that says it is version 3 but holds only version 2's digest is refused (the digest was swapped);
    one that says it is a version this code does not know is refused, naming the key."""
    record = _write(tmp_path, 2)
    info = json.loads(record.run_json.read_text())
    record.run_json.write_text(json.dumps(info | {"record_version": 3}))
    with pytest.raises(RecordError, match=r"no record_digest, though the version that wrote it \(record version 3\)"):
        verified(record)
    record.run_json.write_text(json.dumps(info | {"record_version": RECORD_VERSION + 1}))
    with pytest.raises(RecordError, match=rf"run.json: record_version is {RECORD_VERSION + 1}, not a record version"):
        verified(record)


def test_a_version_its_keys_contradict_is_refused(tmp_path):
    """A finished record edited (PSNR 99), its digest removed and ``record_version: 1`` added read as version 1,
    which takes no digest, and entered the tables; its ``candidate_filters`` shows a digest-taking version wrote
    it, so the claim is refused, naming the key."""
    record = _write(tmp_path, 3, versioned=True)
    record.steps_path.write_text(record.steps_path.read_text().replace('"psnr": 20.0', '"psnr": 99.0', 1))
    info = json.loads(record.run_json.read_text())
    del info["record_digest"]
    record.run_json.write_text(json.dumps(info | {"record_version": 1}))
    with pytest.raises(RecordError, match="record_version is 1, but run.json holds keys only version 2 and later"):
        verified(record)


def test_an_edited_row_of_an_older_version_still_fails_its_digest(tmp_path):
    record = _write(tmp_path, 2)
    record.steps_path.write_text(record.steps_path.read_text().replace('"psnr": 20.0', '"psnr": 30.0', 1))
    with pytest.raises(RecordError, match=r"steps.jsonl: differs from the digest run.json took .*\(steps_digest\)"):
        verified(record)


def _committed() -> dict[int, list[Path]]:
    found: dict[int, list[Path]] = {}
    for run_json in sorted((REPO / "results").rglob("run.json")):
        found.setdefault(record_version(json.loads(run_json.read_text())), []).append(run_json.parent)
    return found


def test_committed_records_of_every_older_version_read_as_the_current_one():
    """The committed records hold versions 1 to 3 (before record_version was written); each reads as the current
    version with every value it holds unchanged: the upgrades only add keys (the first ``SAMPLE`` of each version:
    ``tests/test_records.py`` verifies them all)."""
    committed = _committed()
    if not committed:
        pytest.skip("no committed records in this checkout")
    assert set(committed) == {1, 2, 3}, sorted(committed)
    for directories in committed.values():
        for directory in directories[:SAMPLE]:
            info, rows = verified(RunRecord(directory))
            current, current_rows = upgraded(info, rows)
            assert {key: current[key] for key in info} == info
            assert current["record_version"] == RECORD_VERSION
            assert isinstance(current["candidate_filters"], bool) and isinstance(current["collision_free"], bool)
            for row, current_row in zip(rows, current_rows, strict=True):
                assert {key: current_row[key] for key in row if key != "candidate_scores"} == {
                    key: value for key, value in row.items() if key != "candidate_scores"
                }
                assert current_row["candidate_scores"] == {"ties_at_max": None} | row["candidate_scores"]
