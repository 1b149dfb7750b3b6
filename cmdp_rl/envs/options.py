"""Options every env shares, whatever its backend; each env's options class extends
:class:`EnvOptions`."""

from __future__ import annotations

from cmdp_rl.validation import Bool, options


@options
class EnvOptions:
    """``allow_negative_cost``: accept negative costs (a CMDP's costs are >= 0, and the env contract
    stops a run on a negative one, ``envs/contract.py``; set it for an env whose signed costs you
    mean)."""

    allow_negative_cost: Bool = False

    def env_id(self) -> str:
        """How the env contract's messages name this env."""
        return getattr(self, "id", "") or getattr(self, "name", "env")
