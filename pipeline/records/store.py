"""Run records: one directory per run with run.json, steps.jsonl and a DONE or FAILED marker.

Layout: ``<outputs>/<scene>/<method>-<planner>-<ablation>/<budget>/seed_<seed>/``, derived only
from validated keys. Every write is atomic (temp file in the same directory, fsync, ``os.replace``,
fsync of the directory): a killed run leaves the old file or the new one, never a half-written row.
Values are strict JSON: numpy/torch scalars and arrays become numbers and lists, and non-finite
floats (NaN, inf) are written as ``null``; readers (``pipeline.tables``) read ``null`` back as NaN.
"""

import dataclasses
import hashlib
import importlib.metadata
import json
import math
import os
import re
import secrets
import shutil
import subprocess
import warnings
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from types import MappingProxyType
from typing import Any

from pipeline.metrics.info import METRICS
from pipeline.records.compat import drop_not_settings, drop_retired, with_legacy_defaults
from pipeline.records.files import RecordError, is_plain_file, read_plain_file
from pipeline.repo import REPO

CONTROL = re.compile(r"[\x00-\x1f\x7f]")  # control characters: never part of a record's text
KEY_PATTERN = re.compile(r"[A-Za-z0-9_.-]+")
KEY_MAX_LENGTH = 64  # a run key is one path component and part of figure names: 64 characters at most
MAX_SEED = 2**63 - 1  # seeds are int64 (torch.manual_seed, the run generators)
IDENTITY_KEYS = ("scene", "method", "planner", "ablation", "budget", "seed")
RUN_JSON = "run.json"
STEPS = "steps.jsonl"
DONE = "DONE"
FAILED = "FAILED"
RECORD_FILES = (RUN_JSON, STEPS, DONE, FAILED)  # written only by the run's lock holder
TEMP_SUFFIX = ".tmp"
DIGEST_KEY = "record_digest"  # run.json: record_digest of run.json and steps.jsonl, written when the run finishes
LEGACY_DIGEST_KEY = "steps_digest"  # run.json of records finished before DIGEST_KEY: file_digest of steps.jsonl alone
MAX_RECORD_BYTES = 16 << 20  # run.json, steps.jsonl, DONE, FAILED: a 1000-step record holds about 2 MB

# Distribution names to try per package (the first one installed wins).
PACKAGES = (
    ("torch", ("torch",)),
    ("numpy", ("numpy",)),
    ("nvf-bench", ("nvf-bench",)),
    ("hydra-core", ("hydra-core",)),
    ("lpips", ("lpips",)),
    ("open3d", ("open3d", "open3d-cpu")),
    ("trimesh", ("trimesh",)),
    ("pyrender", ("pyrender", "pyrender-maintained")),
)

METRIC_DEFINITIONS = MappingProxyType({m.name: m.definition for m in METRICS.values()})


def check_key(name: str, value: object, kind: str = "run key") -> str:
    """Return ``value`` if it is a safe single path component of at most ``KEY_MAX_LENGTH`` characters,
    else raise ValueError naming the key (``kind``: what ``name`` is, e.g. an ``option`` on the command line)."""
    if not isinstance(value, str) or not KEY_PATTERN.fullmatch(value) or value in (".", ".."):
        shown = value if not isinstance(value, str) or len(value) <= KEY_MAX_LENGTH else f"{value[:KEY_MAX_LENGTH]}..."
        raise ValueError(f"{kind} {name}={shown!r} is not a plain name: use letters, digits, '_', '.', '-'")
    if len(value) > KEY_MAX_LENGTH:
        raise ValueError(
            f"{kind} {name}={value[:KEY_MAX_LENGTH]!r}... has {len(value)} characters, more than {KEY_MAX_LENGTH}"
        )
    return value


def check_seed(seed: object) -> int:
    """Return ``seed`` if it is an integer in ``[0, MAX_SEED]``, else raise ValueError."""
    if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed <= MAX_SEED:
        digits = str(seed) if isinstance(seed, int) else ""
        shown = f"{digits[:20]}... ({len(digits)} digits)" if len(digits) > 30 else repr(seed)
        raise ValueError(f"seed {shown} is not an integer from 0 to 2^63-1")
    return seed


def run_dir(outputs: Path, scene: str, method: str, planner: str, ablation: str, budget: str, seed: int) -> Path:
    """Directory of one run, derived only from validated keys (never outside ``outputs``)."""
    for name, value in (("method", method), ("planner", planner), ("ablation", ablation)):
        if "-" in check_key(name, value):
            raise ValueError(f"run key {name}={value!r} must not contain '-' (it separates method-planner-ablation)")
    check_seed(seed)
    group = f"{method}-{planner}-{ablation}"
    return Path(outputs) / check_key("scene", scene) / group / check_key("budget", budget) / f"seed_{seed}"


def to_jsonable(value: Any) -> Any:
    """Strict-JSON copy of ``value``: mappings, sequences, dataclasses, numpy/torch scalars and arrays
    to Python; non-finite floats to None."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Mapping):  # dict, or a mapping config node
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, Sequence):  # list, tuple, or a sequence config node (str handled above)
        return [to_jsonable(v) for v in value]
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return to_jsonable(dataclasses.asdict(value))
    if hasattr(value, "tolist"):  # numpy and torch scalars/arrays (moved to the CPU first)
        return to_jsonable(value.cpu().tolist() if hasattr(value, "cpu") else value.tolist())
    raise TypeError(f"cannot record a value of type {type(value).__name__} in a run record")


def utc_now() -> str:
    """Current UTC time, ISO 8601 with seconds."""
    return datetime.now(UTC).isoformat(timespec="seconds")


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (``atomic_write_bytes``)."""
    atomic_write_bytes(path, text.encode("utf-8"))


def temp_file(path: Path) -> tuple[int, Path]:
    """A new, empty temp file beside ``path``, unique to this writer: ``.<name>.<pid>.<random>.tmp``.

    Opened write-only with mode 0o666 less the umask, the mode any new file of this process gets
    (``tempfile.mkstemp`` would make it 0600). Returns the descriptor and the path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{TEMP_SUFFIX}"
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp
        except FileExistsError:
            continue


def temp_folder(path: Path) -> Path:
    """A new, empty folder beside ``path``, unique to this writer (``.<name>.<pid>.<random>.new``), made as any new
    folder of this process is (0o777 less the umask): where a folder that will replace ``path`` is built."""
    while True:
        folder = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.new"
        try:
            os.mkdir(folder, 0o777)
            return folder
        except FileExistsError:
            continue


def replace_folder(new: Path, path: Path) -> None:
    """Put the folder ``new`` (beside ``path``) in the place of ``path`` by renames: ``path`` (a folder, a link or
    nothing) renamed aside, ``new`` renamed to ``path`` (the old one put back if that fails), then the old one
    removed. A reader sees the old folder or the new one whole, never a mix."""
    old = None
    if os.path.lexists(path):
        old = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.old"
        os.rename(path, old)
    try:
        os.rename(new, path)
    except BaseException:
        if old is not None:
            os.rename(old, path)
        raise
    if old is not None and (old.is_symlink() or not old.is_dir()):
        old.unlink()
    elif old is not None:
        shutil.rmtree(old)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temp file of this writer in the same directory (``temp_file``),
    fsync and ``os.replace``; the file's mode follows the umask."""
    fd, tmp = temp_file(path)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def file_digest(data: bytes) -> str:
    """``sha256:<hex>`` of a file's bytes (``LEGACY_DIGEST_KEY``)."""
    return "sha256:" + hashlib.sha256(data).hexdigest()


def record_digest(info: Mapping, steps: bytes) -> str:
    """``sha256:<hex>`` of run.json's content (every key but the digests, as canonical JSON) and the bytes of
    steps.jsonl: editing either after the run finished (its config, its method, a row) breaks it."""
    content = {k: v for k, v in to_jsonable(info).items() if k not in (DIGEST_KEY, LEGACY_DIGEST_KEY)}
    canonical = json.dumps(content, sort_keys=True, ensure_ascii=True, separators=(",", ":"), allow_nan=False)
    return "sha256:" + hashlib.sha256(canonical.encode("ascii") + b"\n" + steps).hexdigest()


def dumps(value: Any) -> str:
    """One-line strict JSON of ``value`` (after ``to_jsonable``)."""
    return json.dumps(to_jsonable(value), allow_nan=False, separators=(",", ":"))


def git_state(repo: Path) -> dict[str, Any]:
    """``{"commit", "dirty"}`` of the git checkout at ``repo``; both None when it is not one."""
    try:
        head, status = (
            subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=30)
            for args in (("rev-parse", "HEAD"), ("status", "--porcelain"))
        )
    except (OSError, subprocess.TimeoutExpired):
        return {"commit": None, "dirty": None}
    if head.returncode != 0 or status.returncode != 0:
        return {"commit": None, "dirty": None}
    return {"commit": head.stdout.strip(), "dirty": bool(status.stdout.strip())}


def package_versions() -> dict[str, str | None]:
    """Installed versions of the packages a run depends on (None when absent); imports nothing."""
    versions: dict[str, str | None] = {}
    for name, distributions in PACKAGES:
        versions[name] = None
        for dist in distributions:
            try:
                versions[name] = importlib.metadata.version(dist)
                break
            except importlib.metadata.PackageNotFoundError:
                continue
    return versions


def read_steps(path: Path) -> tuple[list[dict], str | None]:
    """Valid rows of a steps.jsonl (read-only) and a note on a dropped truncated/corrupt last line.

    A bad line before the last one is not a kill artifact: RecordError.
    """
    data = read_plain_file(path, MAX_RECORD_BYTES)
    if data is None:
        return [], None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise RecordError(f"{path}: not UTF-8 text ({err.reason} at byte {err.start}); delete the run") from None
    lines = text.split("\n")
    complete, tail = lines[:-1], lines[-1]  # tail is "" when the file ends with a newline
    rows: list[dict] = []
    for number, line in enumerate(complete, start=1):
        row = _parse_row(line)
        if row is None:
            if number < len(complete) or tail:
                raise RecordError(f"{path}: line {number} is corrupt and not the last one; fix or delete the run")
            return rows, f"{path}: dropped a corrupt last line (line {number})"
        rows.append(row)
    if tail:
        return rows, f"{path}: dropped a truncated last line (line {len(complete) + 1}, no newline)"
    return rows, None


def _parse_row(line: str) -> dict | None:
    try:
        row = json.loads(line)
    except (json.JSONDecodeError, RecursionError):  # RecursionError: nested deeper than the parser goes
        return None
    if not isinstance(row, dict) or not isinstance(row.get("step"), int) or isinstance(row.get("step"), bool):
        return None
    return row


def _settings(config: Any) -> Any:
    """A resolved config without its ``paths`` group (locations, not experiment settings) and without the
    keys the schema has retired (``pipeline.records.compat``)."""
    return {k: v for k, v in drop_retired(config).items() if k != "paths"} if isinstance(config, Mapping) else config


def _comparable(config: Any) -> Any:
    """``_settings`` without the groups that are not settings (``compat.NOT_SETTINGS``: measurements that
    never change a run's views or metrics)."""
    return drop_not_settings(_settings(config))


def first_difference(old: Any, new: Any, prefix: str = "") -> tuple[str, Any, Any] | None:
    """Dotted key and both values of the first difference between two JSON values (None when equal)."""
    if isinstance(old, dict) and isinstance(new, dict):
        for key in sorted(old.keys() | new.keys()):
            found = first_difference(old.get(key), new.get(key), f"{prefix}{key}.")
            if found is not None:
                return found
        return None
    return None if old == new else (prefix.rstrip(".") or "value", old, new)


def run_difference(
    old_info: Mapping, new_info: Mapping, labels: tuple[str, str] = ("in the record", "now")
) -> str | None:
    """How two run infos differ as runs: ``<key> (<old> <labels[0]>, <new> <labels[1]>)`` for the
    first differing identity key or setting (``config.<dotted key>``; ``paths`` are locations, not
    settings), or None when both describe the same run. A key one config lacks and the other has is
    read as the value its record was made with (``pipeline.records.compat``)."""
    old_config, new_config = (to_jsonable(_comparable(info.get("config"))) for info in (old_info, new_info))
    old_config, new_config = with_legacy_defaults(old_config, new_config), with_legacy_defaults(new_config, old_config)
    old = {k: old_info.get(k) for k in IDENTITY_KEYS} | {"config": old_config}
    new = {k: new_info.get(k) for k in IDENTITY_KEYS} | {"config": new_config}
    found = first_difference(to_jsonable(old), to_jsonable(new))
    if found is None:
        return None
    key, was, now = found
    return f"{key} ({json.dumps(was)} {labels[0]}, {json.dumps(now)} {labels[1]})"


def record_status(info: dict, directory: Path) -> str:
    """``done``, ``failed`` or ``unfinished`` from the markers or from run.json (committed records)."""
    if is_plain_file(directory / DONE) or info.get("status") == "done":
        return "done"
    if is_plain_file(directory / FAILED) or info.get("status") == "failed":
        return "failed"
    return "unfinished"


class RunRecord:
    """The files of one run directory: run.json, steps.jsonl and the DONE / FAILED markers."""

    def __init__(self, directory: Path):
        self.directory = Path(directory)
        self.run_json = self.directory / RUN_JSON
        self.steps_path = self.directory / STEPS

    def info(self) -> dict:
        """Contents of run.json ({} when the run has not started); RecordError when it is not a JSON object."""
        data = read_plain_file(self.run_json, MAX_RECORD_BYTES)
        if data is None:
            return {}
        try:
            info = json.loads(data.decode("utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise RecordError(f"{self.run_json}: not valid JSON ({getattr(err, 'msg', err)})") from None
        except RecursionError:
            raise RecordError(f"{self.run_json}: not valid JSON (nested deeper than a record may be)") from None
        if not isinstance(info, dict):
            raise RecordError(f"{self.run_json}: a JSON {type(info).__name__}, not an object")
        return info

    def start(self, info: dict, repo: Path | None = None) -> None:
        """Create the directory and write run.json: ``info`` plus git state, versions, definitions, timings.

        ``info`` holds at least the identity keys (scene, method, planner, ablation, budget, seed) and
        ``config``. The config is stored without its ``paths`` group (where files live on this machine,
        not a setting), so records are the same on every machine. Resuming keeps the first start time;
        a different identity or config (apart from ``paths``) is refused, naming the first differing key,
        and so are rows without a run.json (their settings are unknown). The caller holds the run's lock
        (``pipeline.records.lock``): only it removes the temp files of a killed write.
        """
        missing = [key for key in (*IDENTITY_KEYS, "config") if key not in info]
        if missing:
            raise ValueError(f"run info for {self.directory} lacks {', '.join(missing)}")
        if self.status() != "unfinished":
            raise ValueError(f"run {self.directory} is already {self.status()}; delete it to run it again")
        previous = self.info()
        if not previous and os.path.lexists(self.steps_path):
            raise RecordError(f"{self.steps_path}: rows without run.json (settings unknown); delete {self.directory}")
        now = utc_now()
        timings: dict[str, Any] = {"started": now, "resumed": [], "ended": None}
        if previous:
            changed = run_difference(previous, info)
            if changed is not None:
                message = f"run {self.directory} was started with a different {changed}"
                raise ValueError(f"{message}; delete it or restore that setting")
            timings = {**previous.get("timings", timings), "ended": None}
            timings["resumed"] = [*timings.get("resumed", []), now]
        for name in RECORD_FILES:  # temp files of a killed write of this run (the caller holds its lock)
            for stale in self.directory.glob(f".{name}.*{TEMP_SUFFIX}"):
                stale.unlink(missing_ok=True)
        repo = REPO if repo is None else repo
        record = {
            **info,
            "config": _settings(info["config"]),
            "status": "running",
            "git": git_state(repo),
            "versions": package_versions(),
            "metric_definitions": dict(METRIC_DEFINITIONS),
            "timings": timings,
        }
        atomic_write_text(self.run_json, json.dumps(to_jsonable(record), indent=2, allow_nan=False) + "\n")

    def difference(self, info: Mapping) -> str | None:
        """``run_difference`` between this record's run.json and ``info`` (None when there is no record)."""
        previous = self.info()
        return run_difference(previous, info) if previous else None

    def completed_steps(self) -> list[dict]:
        """Valid step rows; a truncated/corrupt last line is dropped, the file rewritten and a warning issued."""
        rows, dropped = read_steps(self.steps_path)
        if dropped is not None:
            self._write_steps(rows)
            restart = rows[-1]["step"] + 1 if rows else 0
            warnings.warn(f"{dropped}; restarting from step {restart}", RuntimeWarning, stacklevel=2)
        return rows

    def append_step(self, row: dict) -> None:
        """Append one step row (JSON-safe copy); the whole file is rewritten atomically."""
        clean = to_jsonable(row)
        step = clean.get("step")
        if not isinstance(step, int) or isinstance(step, bool):
            raise ValueError(f"step row for {self.directory} needs an integer 'step'")
        rows = self.completed_steps()
        if rows and step <= rows[-1]["step"]:
            raise ValueError(f"step {step} already recorded in {self.steps_path} (last step {rows[-1]['step']})")
        self._write_steps([*rows, clean])

    def _write_steps(self, rows: list[dict]) -> None:
        atomic_write_text(self.steps_path, "".join(dumps(row) + "\n" for row in rows))

    def mark_done(self) -> None:
        """Record the run as finished: run.json status and end time, then the DONE marker."""
        self._finish("done", {})
        atomic_write_text(self.directory / DONE, utc_now() + "\n")

    def is_done(self) -> bool:
        """True when the run finished (DONE marker or a committed run.json saying so)."""
        return self.status() == "done"

    def mark_failed(self, reason: str) -> None:
        """Record the run as failed (e.g. a diverged step) with a one-line reason."""
        reason = " ".join(CONTROL.sub(" ", reason).split())  # one line of printable text
        self._finish("failed", {"failure_reason": reason})
        atomic_write_text(self.directory / FAILED, reason + "\n")

    def failure(self) -> str | None:
        """The failure reason, or None when the run has not failed."""
        if self.status() != "failed":
            return None
        marker = read_plain_file(self.directory / FAILED, MAX_RECORD_BYTES)
        fallback = marker.decode("utf-8", "replace").strip() if marker is not None else "unknown"
        return self.info().get("failure_reason") or fallback

    def status(self) -> str:
        """``done``, ``failed`` or ``unfinished``."""
        return record_status(self.info(), self.directory)

    def _finish(self, status: str, extra: dict) -> None:
        """run.json's status, end time and the digest of run.json's content and steps.jsonl (``DIGEST_KEY``)."""
        info = self.info()
        if not info:
            raise ValueError(f"run {self.directory} has no run.json; call start() first")
        timings = {**info.get("timings", {}), "ended": utc_now()}
        record = to_jsonable({**info, **extra, "status": status, "timings": timings})
        record[DIGEST_KEY] = record_digest(record, read_plain_file(self.steps_path, MAX_RECORD_BYTES) or b"")
        atomic_write_text(self.run_json, json.dumps(record, indent=2, allow_nan=False) + "\n")
