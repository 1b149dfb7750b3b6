"""The MuJoCo Warp side of ``env=safe_nav`` (``env.physics=mjwarp``, docs/safe_nav.md): ``world.py``'s
model with one Warp world per env; layouts placed on a host copy, then copied into that env's world;
an env step recorded once as a graph and replayed (kernel launches one by one cost far more than the
physics). MuJoCo Warp's float32 solver gives trajectories close to ``mujoco``'s, not equal."""

from __future__ import annotations

import importlib.util

import numpy as np
import torch

from cmdp_rl.envs.safe_nav.spec import FRAMESKIP, NavSpec
from cmdp_rl.envs.safe_nav.world import NavWorlds

# The Goal tasks without vase costs (those read MuJoCo's contact list, which MuJoCo Warp lays out differently).
WARP_TASKS = ("PointGoal0", "PointGoal1", "CarGoal0", "CarGoal1")

# Model fields that placing a layout changes (tested against every MjModel field): one row per world.
PER_WORLD = ("body_pos", "body_quat", "qpos0", "qpos_spring", "body_invweight0", "dof_invweight0", "actuator_acc0")
# Capacity per world: contacts, constraint rows (10 per condim-6 contact; a robot, a vase, the floor stay below).
NCONMAX, NJMAX = 48, 256


def warp_problem() -> str | None:
    """None if MuJoCo Warp can be imported, else the one-line config error saying how to get it."""
    if importlib.util.find_spec("mujoco_warp") is None or importlib.util.find_spec("warp") is None:
        return "env.physics: mjwarp needs MuJoCo Warp: pip install -e '.[mjwarp]' (or env.physics=mujoco)"
    return None


class WarpWorlds:
    """N worlds of one task on MuJoCo Warp: :class:`NavWorlds`' interface, torch tensors on ``device``."""

    def __init__(self, spec: NavSpec, num_envs: int, device: torch.device) -> None:
        import mujoco
        import mujoco_warp as mjw
        import warp as wp

        self.mj, self.mjw, self.wp = mujoco, mjw, wp
        wp.config.quiet = True
        self.host = NavWorlds(spec, 1)  # places layouts with MuJoCo's own compiler steps
        h = self.host
        self.spec, self.agent, self.goal, self.hazards, self.vases = h.spec, h.agent, h.goal, h.hazards, h.vases
        self.ctrl_low, self.ctrl_high, self.goal_z = h.ctrl_low, h.ctrl_high, h.goal_z
        self.models = h.models  # the host model: names and sizes (one, not N)
        self.device = torch.device(device)
        self.wp_device = "cpu" if self.device.type == "cpu" else f"cuda:{self.device.index or 0}"
        self._n = num_envs
        m, d = h.models[0], h.datas[0]
        self.state_kind = mujoco.mjtState.mjSTATE_INTEGRATION
        self.state_size = mujoco.mj_stateSize(m, self.state_kind)
        with wp.ScopedDevice(self.wp_device):
            self.model = mjw.put_model(m, batch_sizes={f: num_envs for f in PER_WORLD})
            self.data = mjw.put_data(m, d, nworld=num_envs, nconmax=NCONMAX, njmax=NJMAX)
            self._states = wp.zeros((num_envs, self.state_size), dtype=float)
            self._active = wp.zeros(num_envs, dtype=bool)
        view = wp.to_torch
        self.fields = {f: view(getattr(self.model, f)) for f in PER_WORLD}
        self.states, self.active = view(self._states), view(self._active)
        self.ctrl = view(self.data.ctrl)
        self.sensordata, self.xpos = view(self.data.sensordata), view(self.data.xpos)
        self.agent_mat = view(self.data.xmat)[:, self.agent]  # a view: [N, 3, 3]
        self.proto = self.xpos.new_zeros(0)  # the task logic's arrays: this library, device, dtype
        self.low = torch.as_tensor(self.ctrl_low, dtype=self.ctrl.dtype, device=self.device)
        self.high = torch.as_tensor(self.ctrl_high, dtype=self.ctrl.dtype, device=self.device)
        self._staged: dict[int, tuple[dict[str, np.ndarray], np.ndarray]] = {}
        self._graphs: dict[str, object] = {}

    @property
    def num_envs(self) -> int:
        return self._n

    def place(self, i: int, layout: dict) -> None:
        """Env ``i`` starts over from ``layout``; written to the device at the next read or step."""
        h, mj = self.host, self.mj
        h.place(0, layout)
        m, d = h.models[0], h.datas[0]
        state = np.empty(self.state_size)
        mj.mj_getState(m, d, state, self.state_kind)
        self._staged[i] = ({f: getattr(m, f).copy() for f in PER_WORLD}, state)

    def _flush(self) -> None:
        """Write the staged layouts to their worlds, then recompute positions and sensors (all worlds)."""
        if not self._staged:
            return
        envs = sorted(self._staged)
        rows = [self._staged[i] for i in envs]
        idx = torch.as_tensor(envs, device=self.device)
        for f, view in self.fields.items():
            values = np.stack([r[0][f] for r in rows]).reshape((len(envs),) + tuple(view.shape[1:]))
            view[idx] = torch.as_tensor(values, dtype=view.dtype, device=self.device)
        self.states[idx] = torch.as_tensor(np.stack([r[1] for r in rows]), dtype=self.states.dtype, device=self.device)
        self.active.zero_()
        self.active[idx] = True
        self._staged.clear()
        self._replay("start", self._set_states)

    def move_goal(self, i: int, xy: np.ndarray) -> None:
        """A new goal mid-episode: the goal has no contacts, so only its position changes."""
        self.fields["body_pos"][i, self.goal, :2] = torch.as_tensor(xy, dtype=self.xpos.dtype, device=self.device)

    def step(self, ctrl: torch.Tensor) -> None:
        """One env step of every world: ``ctrl`` ``[N, nu]`` (clipped to the actuators' range)."""
        self._flush()
        self.ctrl.copy_(torch.clamp(ctrl.to(self.ctrl.dtype), self.low, self.high))
        self._replay("step", self._physics)

    def _replay(self, name: str, launches) -> None:
        """Run ``launches`` (always on the same arrays) as a graph, recorded on the first call. On a GPU,
        Warp's stream waits for torch's and then torch's for Warp's: events, no host synchronisation."""
        wp = self.wp
        cuda = self.device.type == "cuda"
        with wp.ScopedDevice(self.wp_device):
            if cuda:
                wp.get_stream().wait_stream(wp.stream_from_torch(self.device))
            if name not in self._graphs:
                with wp.ScopedCapture() as capture:
                    launches()
                self._graphs[name] = capture.graph
            wp.capture_launch(self._graphs[name])
            if cuda:
                wp.stream_from_torch(self.device).wait_stream(wp.get_stream())

    def _physics(self) -> None:
        for _ in range(FRAMESKIP):
            self.mjw.step(self.model, self.data)
        self.mjw.forward(self.model, self.data)

    def _set_states(self) -> None:
        """The worlds marked in ``active`` take the states in ``states``; positions and sensors follow."""
        self.mjw.set_state(self.model, self.data, self._states, int(self.state_kind), self._active)
        self.mjw.forward(self.model, self.data)

    def gather(self, envs) -> dict[str, torch.Tensor]:
        """:meth:`NavWorlds.gather`, of Warp's arrays viewed as torch tensors on the device."""
        self._flush()
        return NavWorlds.gather(self, envs)

    def get_states(self) -> np.ndarray:
        """Every world's MuJoCo integration state ``[N, size]`` (float32 on Warp)."""
        self._flush()
        self.active.fill_(True)
        self._replay(
            "get", lambda: self.mjw.get_state(self.model, self.data, self._states, int(self.state_kind), self._active)
        )
        return self.states.cpu().numpy().copy()

    def set_states(self, states: np.ndarray) -> None:
        """Every world continues from ``states`` (after its layout was placed)."""
        self._flush()
        self.states.copy_(torch.as_tensor(np.stack(states), dtype=self.states.dtype))
        self.active.fill_(True)
        self._replay("start", self._set_states)

    def close(self) -> None:
        self.host.close()
