"""``hydra/sweeper=cmdp_optuna``: maximise the deployed policy's return subject to each cost within its budget.

Why our own sweeper and not hydra-optuna-sweeper (1.2.0, the latest): that plugin requires optuna < 3 (we take
optuna 4), tells Optuna only the job's return value (train.py's returns nothing, and a constraint needs each
trial's costs beside its objective: Optuna's ``constraints_func`` reads them from the trial), counts
``n_trials`` per process (two workers on one study would run twice as many), leaves a killed job's trial
RUNNING for ever, and has no pruning. What it does do, we reuse: the override grammar for the space
(``interval``, ``range``, ``choice``, ``tag(log, ...)``) and any ``hydra/launcher`` for the jobs. The search is
:mod:`cmdp_rl.tune.search`; this module is only Hydra's entry point to it, and imports nothing heavy, because
Hydra imports every plugin module at the start of every command.
"""

from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional

from hydra.core.config_store import ConfigStore
from hydra.core.plugins import Plugins
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


@dataclass
class ConstrainedOptunaConf:
    """The sweeper's options (``hydra.sweeper.*``), documented with examples in configs/tune/*.yaml."""

    _target_: str = "hydra_plugins.cmdp_tune.sweeper.ConstrainedOptunaSweeper"
    # The sampler's and the pruner's _target_ are built by the search (the sampler with the constraint, the
    # pruner in each job), not by Hydra when it builds the sweeper.
    _recursive_: bool = False
    params: Dict[str, Any] = field(default_factory=dict)
    study_name: str = "tune"
    storage: Optional[str] = None
    n_trials: int = 20
    seeds: int = 3
    n_jobs: int = 1
    budget: Any = None
    feasible_by: str = "upper"
    sampler: Dict[str, Any] = field(default_factory=lambda: {"_target_": "optuna.samplers.TPESampler", "seed": 0})
    pruner: Optional[Dict[str, Any]] = field(
        default_factory=lambda: {"_target_": "optuna.pruners.MedianPruner", "n_startup_trials": 5}
    )
    prune_after: float = 0.5
    heartbeat_s: int = 10
    grace_s: int = 30
    max_failures: int = 3
    report: bool = True


ConfigStore.instance().store(group="hydra/sweeper", name="cmdp_optuna", node=ConstrainedOptunaConf, provider="cmdp_rl")


class ConstrainedOptunaSweeper(Sweeper):
    def __init__(self, **options: Any) -> None:
        self.options = options
        self.config: Optional[DictConfig] = None
        self.hydra_context: Optional[HydraContext] = None
        self.launcher = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config, self.hydra_context = config, hydra_context
        self.launcher = Plugins.instance().instantiate_launcher(
            config=config, hydra_context=hydra_context, task_function=task_function
        )

    def sweep(self, arguments: List[str]) -> Any:
        from cmdp_rl.tune.search import sweep

        return sweep(self, arguments)
