"""The protocols two classes meet are declared (``typing.Protocol``) and type-checked: mypy checks that a run's and a
population's classes each meet the protocol the code that drives them is written against (docs/architecture.md,
"Glossary"), and that it refuses a class that does not (so the check is not vacuous)."""

import subprocess
import sys
import textwrap

from helpers.runs import ROOT

CHECK = """
from cmdp_rl.algos.learner import Learner, SingleLearner
from cmdp_rl.envs.vector import VecEnv
from cmdp_rl.policies.agent import Agent
from cmdp_rl.population.kernel import StackedKernel
from cmdp_rl.population.learner import StackedLearner
from cmdp_rl.population.stacked import PopulationAgent
from cmdp_rl.rollout.advantages import Valuing
from cmdp_rl.rollout.collector import Acting, Envs
from cmdp_rl.run.kernel import AgentKernel, Kernel


def learners(one: SingleLearner, stacked: StackedLearner) -> list[Learner]:
    return [one, stacked]  # what ppo_update, CUP's projection and the critic fit step


def kernels(one: AgentKernel, stacked: StackedKernel) -> list[Kernel]:
    return [one, stacked]  # what the training loop trains


def acting(one: Agent, stacked: PopulationAgent) -> list[Acting]:
    return [one, stacked]  # what the collector acts with


def valuing(one: Agent, stacked: PopulationAgent) -> list[Valuing]:
    return [one, stacked]  # what GAE values with


def envs(env: VecEnv) -> Envs:
    return env  # what the collector steps


def not_a_learner(agent: Agent) -> Learner:
    return agent  # REFUSED
"""


def test_each_protocol_is_met_by_the_classes_that_claim_it(tmp_path):
    check = tmp_path / "protocols_check.py"
    check.write_text(textwrap.dedent(CHECK))
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--follow-imports=silent", "--ignore-missing-imports", "--no-error-summary",
         "--cache-dir", str(tmp_path / "cache"), str(check)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    errors = [line for line in proc.stdout.splitlines() if ": error:" in line]
    refused = next(i for i, line in enumerate(CHECK.splitlines()) if "REFUSED" in line)
    assert [e.split(":")[1] for e in errors] == [str(refused + 1)], proc.stdout + proc.stderr
