"""Older run records read as the current version (``pipeline.records.schema.RECORD_VERSION``): one upgrade per
version, from N to N + 1 (``UPGRADES``), applied in turn from the record's own version (``record_version``).

A record's version is run.json's ``record_version``. Records from before it was written are told apart by what they
hold (``inferred_version``):

- version 1: run.json without ``candidate_filters`` (``DIGEST_ERA_KEY``): written before any digest;
- version 2: ``steps_digest``, the digest of steps.jsonl alone, taken when the run ended;
- version 3: ``record_digest``, the digest of run.json and steps.jsonl; or no digest yet (an unfinished run: versions
  2 and 3 wrote the same keys until the run ended, and a finished one without its digest is refused by
  ``pipeline.records.verify``).

An upgrade adds what an older version did not write, as that version's code chose it; it never changes a value the
record holds, and never touches the record's files (a record is upgraded as it is read, after its digest, which
covers what was written, is checked).
"""

import copy
from collections.abc import Callable

from pipeline.records.compat import chose_collision_free, filters_candidates
from pipeline.records.schema import RECORD_VERSION
from pipeline.records.store import DIGEST_KEY, LEGACY_DIGEST_KEY

VERSION_KEY = "record_version"  # run.json: the record version that wrote it
DIGEST_ERA_KEY = "candidate_filters"  # run.json: written by every version that takes a digest, by none before

Record = tuple[dict, list[dict]]  # run.json's content and the step rows


def inferred_version(info: dict) -> int:
    """The version of a record written before ``record_version`` was (the module's docstring)."""
    if DIGEST_ERA_KEY not in info:
        return 1
    if LEGACY_DIGEST_KEY in info and DIGEST_KEY not in info:
        return 2
    return 3


def lowest_version(info: dict) -> int:
    """The oldest record version that writes every key ``info`` holds: 3 with ``record_digest``, 2 with
    ``candidate_filters`` (``DIGEST_ERA_KEY``), else 1."""
    if DIGEST_KEY in info:
        return 3
    return 2 if DIGEST_ERA_KEY in info else 1


def record_version(info: dict) -> int:
    """run.json's ``record_version`` (an integer from 1 to ``RECORD_VERSION``, no older than the keys it holds:
    ``lowest_version``), else ``inferred_version``; ValueError for a version this code does not know or one its keys
    contradict (an edited record: a version-1 claim would skip the digest its keys show it took)."""
    if VERSION_KEY not in info:
        return inferred_version(info)
    version = info[VERSION_KEY]
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= RECORD_VERSION:
        raise ValueError(
            f"{VERSION_KEY} is {repr(version)[:40]}, not a record version from 1 to {RECORD_VERSION} "
            "(a newer version's record, or an edited one)"
        )
    if version < lowest_version(info):
        raise ValueError(
            f"{VERSION_KEY} is {version}, but run.json holds keys only version {lowest_version(info)} and later "
            "write (an edited record); restore it"
        )
    return version


def version_1_to_2(info: dict, rows: list[dict]) -> Record:
    """run.json gains ``collision_free`` where it lacks it (it was written from before version 2 on) and
    ``candidate_filters``: what version 1's code chose from the config (``compat.chose_collision_free``: the
    configured sampler, else Room's; ``compat.filters_candidates``: every method but Random)."""
    config = info["config"]  # an object: pipeline.records.verify checks it before upgrading
    upgraded = dict(info)
    if not isinstance(info.get("collision_free"), bool):
        upgraded["collision_free"] = chose_collision_free(config, str(info.get("scene")))
    if not isinstance(info.get(DIGEST_ERA_KEY), bool):
        upgraded[DIGEST_ERA_KEY] = filters_candidates(config)
    return upgraded, rows


def version_2_to_3(info: dict, rows: list[dict]) -> Record:
    """Rows' ``candidate_scores`` gain ``ties_at_max`` where they lack it (counted from within version 2 on): null,
    not counted. run.json is the same (version 3 changed its digest, which is checked before upgrading)."""
    upgraded = []
    for row in rows:
        scores = row.get("candidate_scores")
        if isinstance(scores, dict) and "ties_at_max" not in scores:
            row = {**row, "candidate_scores": {**scores, "ties_at_max": None}}
        upgraded.append(row)
    return info, upgraded


UPGRADES: dict[int, Callable[[dict, list[dict]], Record]] = {1: version_1_to_2, 2: version_2_to_3}


def upgraded(info: dict, rows: list[dict]) -> Record:
    """A record (run.json's content and its rows, as verified) read as version ``RECORD_VERSION``: each upgrade
    from its version on, and ``record_version`` set; copies, the arguments untouched."""
    info, rows = copy.deepcopy(info), copy.deepcopy(rows)
    for version in range(record_version(info), RECORD_VERSION):
        info, rows = UPGRADES[version](info, rows)
    return {**info, VERSION_KEY: RECORD_VERSION}, rows
