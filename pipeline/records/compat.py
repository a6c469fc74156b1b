"""Reading records made by older code: config keys the schema no longer has, and what each stood for.

A retired key is dropped from a record's config before it is compared with today's settings (resume,
tables), because its value is implied by keys that remain: it never makes an old record "a different run".
"""

from collections.abc import Mapping
from typing import Any

# what never changes a run's views or metrics (added measurements, whether images are saved): not part of its identity
NOT_SETTINGS = ("diagnostics", "save_images")

RETIRED_KEYS = {
    "method.aux_loss": "implied by method.name: a method's stage-1 loss belongs to its class (nvf.methods)",
}


def drop_retired(config: Any) -> Any:
    """``config`` (a run's resolved config, as recorded) without the ``RETIRED_KEYS``."""
    if not isinstance(config, Mapping):
        return config
    out = {key: dict(value) if isinstance(value, Mapping) else value for key, value in config.items()}
    for dotted in RETIRED_KEYS:
        group, _, key = dotted.partition(".")
        if isinstance(out.get(group), dict):
            out[group].pop(key, None)
    return out
