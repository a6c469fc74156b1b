"""``python -m pipeline.experiments.fan_out -m study=NAME scene=A,B seed=100,101 [args=[...]]
[hydra/launcher=joblib hydra.launcher.n_jobs=2]``: a study's independent units through Hydra's launchers.

A unit is one scene and seed of a study that takes ``--scenes`` and ``--seeds`` (``UNITS``: the duel, the paper
states, the visibility study, the discrimination experiment); each Hydra job runs the study's own command on its
unit (``python -m <module> ARGS --scenes A --seeds 100``) in a process of its own, so every unit resumes on its own
as the study does (a state, a decision set, an episode at a time) and writes into the study's shared folder under
the study's locks. ``args`` are the study's other arguments (its overrides and options, e.g.
``'args=["method=nvf","rival=fvs","--steps","0,3,6"]'``). The launcher is Hydra's: the basic one runs the
units one after another, ``hydra/launcher=joblib hydra.launcher.n_jobs=2`` side by side (one torch thread each:
the studies' ``--threads`` default), ``hydra/launcher=submitit_slurm`` one cluster job per unit (its settings as
for the episodes' sweeps, docs/USAGE.md, "The paper budget on a GPU"). The fan-out ends with one line per failed
unit and exits 1 when any failed (``pipeline.episode.sweep.SweepReport``); the config is
``conf/study/fan_out.yaml``.
"""

import subprocess
import sys

import hydra
from omegaconf import DictConfig

from pipeline.repo import CONF

UNITS = {  # study -> its module (nvf-bench's names: pipeline.commands)
    "duel": "pipeline.experiments.duel",
    "paper-states": "pipeline.experiments.paper_states",
    "visibility": "pipeline.experiments.visibility_study",
    "discriminate": "pipeline.experiments.discriminate",
}
OWN_OPTIONS = ("--scenes", "--seeds")  # the unit's: set by the fan-out


def unit_command(study: str, scene: str, seed: int, args: list[str]) -> list[str]:
    """The study's command on one unit; a ValueError (one line) for a study without units or an ``args`` that
    names the unit's own options."""
    if study not in UNITS:
        raise ValueError(f"study={study!r}: not one that fans out; choose one of {', '.join(UNITS)}")
    own = [arg for arg in args if arg.split("=", 1)[0] in OWN_OPTIONS]
    if own:
        raise ValueError(f"args: {own[0]} is the unit's own; sweep scene= and seed= instead")
    return [sys.executable, "-m", UNITS[study], *args, "--scenes", scene, "--seeds", str(seed)]


@hydra.main(config_path=str(CONF / "study"), config_name="fan_out", version_base="1.3")
def main(cfg: DictConfig) -> dict:
    """One unit: its command run to the end; ``{"status", "reason"}`` for the fan-out's report."""
    try:
        command = unit_command(str(cfg.study), str(cfg.scene), int(cfg.seed), [str(a) for a in cfg.args])
    except ValueError as err:
        return {"status": "failed", "reason": str(err)}
    print(f"[{cfg.study} {cfg.scene} seed {cfg.seed}] python {' '.join(command[1:])}", flush=True)
    done = subprocess.run(command, check=False)
    if done.returncode != 0:
        return {"status": "failed", "reason": f"exit status {done.returncode} (its error line is above)"}
    return {"status": "done", "reason": None}


if __name__ == "__main__":
    main()
