"""pipeline/records/schema.py: the typed row written as the JSON a record holds, and verification reading each
key's type and range from the schema (pipeline.records.verify.schema_problem)."""

import dataclasses
import json

import pytest

from pipeline.records.schema import (
    CandidateScores,
    Metrics,
    OptScores,
    RunInfo,
    StageSummary,
    StepRow,
    StepSeconds,
    as_json,
)
from pipeline.records.store import RecordError, RunRecord, run_dir
from pipeline.records.verify import info_problem, row_problem, schema_problem, verified

METRICS = {field.name: None for field in dataclasses.fields(Metrics)} | {"psnr": 21.5, "num_points": 10}


def _row(**changes) -> StepRow:
    fields = {
        "step": 0,
        "n_views": 3,
        "status": "ok",
        "metrics": Metrics(**METRICS),
        "selected_pose": [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 2.0],
        "selected_index": 2,
        "selected_score": None,
        "refined": False,
        "candidate_scores": CandidateScores(8, None, None, None, None, None),
        "train": {"backbone": StageSummary(10.0, 10.0, 0.5, 0.1, 1.5, samples_per_ray=4.0, rays_per_batch=256.0)},
        "seconds": StepSeconds(train=1.5, eval=0.5, plan=0.25),
    }
    return StepRow(**(fields | changes))


def test_a_row_is_written_in_the_schemas_order_with_the_keys_that_apply():
    row = as_json(_row())
    assert list(row) == [field.name for field in dataclasses.fields(StepRow)][:11]  # no opt, no rank_agreement
    assert list(row["metrics"]) == list(METRICS) and row["metrics"]["ssim"] is None  # null is written
    stage = row["train"]["backbone"]
    assert list(stage) == ["iters", "steps", "first_loss", "last_loss", "seconds", "samples_per_ray", "rays_per_batch"]
    assert row["candidate_scores"] == {
        "count": 8,
        "min": None,
        "mean": None,
        "max": None,
        "std": None,
        "ties_at_max": None,
    }
    with_opt = as_json(_row(opt=OptScores([1.0], [1.5])))
    assert list(with_opt)[-1] == "opt" and with_opt["opt"] == {"original_scores": [1.0], "refined_scores": [1.5]}
    assert schema_problem(json.loads(json.dumps(with_opt)), StepRow) is None


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"refined": "yes"}, "has refined='yes', not bool"),
        ({"n_views": 0}, "has n_views=0, not an integer from 1 to 1000000"),
        ({"status": "failed"}, "has status='failed', not 'ok'"),
        ({"candidate_scores": {"count": 8, "std": -1.0}}, "has candidate_scores.std=-1.0, not a number >= 0 or null"),
        ({"train": {"backbone": {"seconds": "slow"}}}, "has train.backbone.seconds='slow', not a number >= 0"),
        ({"rank_agreement": {"spearman": 2.0}}, "has rank_agreement.spearman=2.0, not a number from -1 to 1 or null"),
        ({"opt": {"original_scores": ["a"]}}, "has opt.original_scores=['a'], not a list (a number or null each)"),
        ({"metrics": {"psnr": 150.0}}, "has metric psnr = 150, outside its range [0, 100]"),  # pipeline.metrics.info
        ({"metrics": {"num_points": 2.5}}, "has metric 'num_points' = '2.5', not an integer from 0 to 2^63-1 or null"),
        ({"selected_pose": [0.0, 0.0, 1.0]}, "has selected_pose=[0.0, 0.0, 1.0], not 7 finite numbers"),
    ],
)
def test_a_row_departing_from_the_schema_is_named_by_its_key(change, message):
    row = json.loads(json.dumps(as_json(_row()))) | change
    assert row_problem(row) == message


def test_keys_a_row_must_hold_and_keys_it_may_lack():
    row = as_json(_row())
    assert row_problem({key: row[key] for key in StepRow.REQUIRED}) is None  # the rest: absent in older records
    assert row_problem({key: value for key, value in row.items() if key != "metrics"}) == "lacks metrics"


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"torch_threads": 0}, "torch_threads is 0, not an integer from 1 to 65536"),
        ({"ground_truth": {"backend": 3}}, "ground_truth.backend is 3, not text"),
        ({"config": {"budget": {"horizon": 5000}}}, "config.budget.horizon is 5000, not an integer from 1 to 1000"),
        ({"config": {"scene": {"paper_scene": 1}}}, "config.scene.paper_scene is 1, not text or null"),
        ({"timings": {"resumed": "now"}}, "timings.resumed is 'now', not a list (text each)"),
        ({"status": "paused"}, "status is 'paused', not 'running' or 'done' or 'failed'"),
    ],
)
def test_run_info_departing_from_the_schema_is_named_by_its_key(change, message):
    info = {"scene": "s", "method": "m", "planner": "p", "ablation": "a", "budget": "b", "seed": 1, "config": {}}
    problem = schema_problem(info | change, RunInfo)
    assert problem is not None and info_problem(problem) == message


def test_verification_refuses_a_record_whose_row_departs_from_the_schema(tmp_path):
    record = RunRecord(run_dir(tmp_path, "default", "nvf", "argmax", "none", "smoke", 100))
    info = {"scene": "default", "method": "nvf", "planner": "argmax", "ablation": "none", "budget": "smoke"}
    record.start(info | {"seed": 100, "config": {"budget": {"horizon": 2}}}, repo=tmp_path)
    record.append_step(as_json(_row()))
    assert len(verified(record)[1]) == 1
    record.append_step(as_json(_row(step=1, seconds=StepSeconds(train=-1.0, eval=0.5, plan=0.25))))
    with pytest.raises(RecordError, match=r"steps.jsonl: step 1 has seconds.train=-1.0, not a number >= 0"):
        verified(record)
