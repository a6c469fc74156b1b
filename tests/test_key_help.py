"""pipeline/config/key_help.py: ``python -m pipeline.run --help-keys`` lists every config key with its default and
its line, read from the config dataclasses' field docstrings."""

import dataclasses
import subprocess
import sys
import typing

from nvf.methods import run_settings
from pipeline.config import key_help
from pipeline.config.catalog import declared, method_configs
from pipeline.config.method import Presentation, method_class
from pipeline.config.structured_configs import RunConfig
from pipeline.repo import REPO


def config_dataclasses(cls: type = RunConfig) -> list[type]:
    """``cls`` and every dataclass its fields hold, depth first."""
    found = [cls]
    for hint in typing.get_type_hints(cls).values():
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            found += [c for c in config_dataclasses(hint) if c not in found]
    return found


def test_every_field_of_every_config_dataclass_has_a_docstring():
    """The schema's and the method library's settings, each method class declared in conf/method and the
    presentation keys: no field without its line."""
    classes = config_dataclasses() + [Presentation]
    classes += [method_class(node["_target_"]) for node in method_configs().values()]
    missing = [
        f"{cls.__name__}.{f.name}"
        for cls in classes
        for f in dataclasses.fields(cls)
        if not key_help.field_docs(cls).get(f.name)
    ]
    assert not missing, missing


def test_every_key_is_listed_with_its_default_and_line():
    """A line per key: the key, its default, its docstring and, where conf/config.yaml (a cpu-budget NVF run)
    sets another value, that value."""
    page = key_help.listing()
    lines = {line.split()[0].rstrip(":"): line for line in page.splitlines() if line.strip() and "." in line.split()[0]}
    for item, _ in key_help.config_keys():
        assert item.doc in lines.get(item.key, page), item.key
    image_size = lines["budget.image_size"]
    assert image_size.split()[1] == "512" and image_size.endswith("[run: 64]")  # the cpu budget's
    rows = {item.key: (item, value) for item, value in key_help.config_keys()}
    assert rows["train.backbone"][0].section and rows["train.backbone.iters"][0].default == "5000"
    assert rows["nvf.entropy.bound"][0].default == "huber" and rows["device"][1] is None


def test_every_schema_field_and_every_methods_keys_are_listed():
    """Each dotted field of the schema appears; each declared method's own keys appear when it is chosen."""

    def dotted(cls: type, prefix: str = "") -> list[str]:
        keys = []
        for f in dataclasses.fields(cls):
            hint = typing.get_type_hints(cls)[f.name]
            keys.append(prefix + f.name)
            if isinstance(hint, type) and dataclasses.is_dataclass(hint):
                keys += dotted(hint, f"{prefix}{f.name}.")
        return keys

    listed = {item.key for item, _ in key_help.config_keys()}
    assert set(dotted(RunConfig)) <= listed
    for name in declared("method"):
        cls = method_class(method_configs()[name]["_target_"])
        own = {f"method.{f.name}" for f in dataclasses.fields(cls) if f.name not in run_settings(cls)}
        keys = {item.key: item for item, _ in key_help.config_keys([f"method={name}"])}
        assert own | {f"method.{key}" for key in ("label", "rank", "experiments")} <= set(keys), name
        assert all(keys[key].doc for key in own), name


def test_the_run_command_lists_the_keys_before_hydra_reads_its_arguments():
    done = subprocess.run(
        [sys.executable, "-m", "pipeline.run", "--help-keys", "budget=smoke", "method=air"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    lines = {line.split()[0]: line for line in done.stdout.splitlines() if line.startswith("  ")}
    assert "[run: 24]" in lines["budget.image_size"] and "M24" in lines["method.reduce"]
    bad = subprocess.run(
        [sys.executable, "-m", "pipeline.run", "--help-keys", "budget=nothing"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert bad.returncode == 2 and bad.stderr.startswith("error: ") and bad.stderr.count("\n") == 1
