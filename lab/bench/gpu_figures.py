"""Issue 43's figures on a GPU, in one call: ``env.physics=mjwarp`` and populations with ``device=cuda``.

    python experiments/speed/gpu_figures.py --stage .gpu              # here: wheels, trimmed Warp, code
    cd .gpu && python experiments/speed/gpu_figures.py --wheels whl --payload payload --out $OUT
    python experiments/speed/gpu_figures.py --tiny --device cpu --out /tmp/gpu_figures   # a rehearsal

The device machine has Python 3.12 and torch but none of MuJoCo, MuJoCo Warp, Warp, TorchRL,
TensorDict, Hydra, pydantic or gymnasium, and nothing can be downloaded there; a call carries at
most 64 MiB. So ``--stage`` gathers here what the device needs (``stage``): this checkout's code, the
wheels our extras resolve to (for CPython 3.12), and Warp cut down to what a CUDA device uses (its
CPU compiler library dropped; the fatbin of its own CUDA kernels kept for Hopper, sm_90, alone; the
library recompressed with xz); the safety_gymnasium package is carried as the two robot models that
``env=safe_nav`` reads from it. On the device, :func:`main` installs all that into ``--site``, then
measures, in the issue's order, each item written as JSON under ``--out`` as soon as it is done
(a call that runs out of time keeps what was written):

1. ``item1_correctness.json``: PointGoal1 and CarGoal1, 200 steps (2 envs, 100-step episodes, so
   episode ends and automatic resets are in it) on the device against MuJoCo on the CPU, each step
   from MuJoCo's state (``compare_physics(forced=True)``), against the tolerances the CPU tests
   assert (``physics_compare.TOLERANCE``); and 100 free-running PointGoal1 steps;
2. ``item2_env.json``: env steps/s of both tasks at N = 1,024, 4,096, 16,384 (random actions; the
   physics a CUDA graph recorded once and replayed, the task logic in torch), the physics graph's
   replay alone, the host's time to place a layout, and device memory per world;
3. ``item3_train.json``: ppo_lag training steps/s on PointGoal1, env and policy on the device,
   N = 4,096, over a measured 1e6 steps, and the time to 1e7 extrapolated from it;
4. ``item4_population.json``: the Reach1D population benchmark's together side at P = 64 and 256;
5. ``item5_learning.json``: PointGoal1 ppo_lag for 2M steps on the device, one seed: eval return
   and cost (the same config on the CPU: docs/safe_nav.md);
6. ``item6_many_worlds.json`` (``--items 6``, issue 53): the many-worlds preset for what the budget allows of
   1e8 steps, its run's files kept under ``item6_run/`` for a campaign record
   (``experiments/benchmarks/campaign.py --import-run``).

``env.json`` records the machine, the versions, the install and the kernels' compile time (Warp's
kernel cache is warmed before any timing). Each item has a share of ``--budget-s``; an item that
would not fit is shortened (and says so) or skipped in one line; an item that fails records its
error and the next one runs.
"""

from __future__ import annotations

import argparse
import csv
import gc
import hashlib
import importlib
import json
import lzma
import math
import os
import platform
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
import traceback
import zipfile
from pathlib import Path
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parents[2]  # the checkout (or the staged copy of it)
TASKS = ("PointGoal1", "CarGoal1")

# What the device lacks, at the versions `make setup-mjwarp` resolves here (the project's pins); the
# image has numpy, scipy, matplotlib, tqdm, pyyaml, cloudpickle, packaging, typing-extensions,
# absl-py and etils (orjson and importlib-metadata, which TensorDict and TorchRL name, are fallbacks
# they do without). antlr4 4.9.3 is a source release: staged as a wheel built here (pure Python).
WHEELS: dict[str, str] = {
    "mujoco": "4.0.0",
    "mujoco-core": "4.0.0",
    "mujoco-warp": "4.0.0",
    "warp-lang": "1.19.0",
    "torchrl": "0.14.1",
    "tensordict": "0.14.3",
    "hoptorch": "0.1.4",
    "pyvers": "0.2.3",
    "hydra-core": "1.3.8",
    "omegaconf": "2.3.1",
    "antlr4-python3-runtime": "4.9.3",
    "pydantic": "2.14.4",
    "pydantic-core": "2.50.5",
    "annotated-types": "0.8.0",
    "typing-inspection": "0.4.5",
    "gymnasium": "1.4.0",
    "farama-notifications": "0.0.6",
}
PLATFORMS = ["manylinux_2_17_x86_64", "manylinux2014_x86_64", "manylinux_2_27_x86_64", "manylinux_2_28_x86_64"]
# Hopper (H100, H200): the one architecture whose machine code of Warp's own kernels is kept.
KEEP_SM = 90
FATBIN_MAGIC = 0xBA55ED50


# --- staging (here) ----------------------------------------------------------------------------
def download_wheels(cache: Path) -> list[Path]:
    """The CPython 3.12 manylinux wheels of :data:`WHEELS` in ``cache`` (downloaded once)."""
    cache.mkdir(parents=True, exist_ok=True)
    for name, version in WHEELS.items():
        stem = name.replace("-", "_").lower()
        if any(p.name.lower().startswith(f"{stem}-") for p in cache.glob("*.whl")):
            continue
        if name == "antlr4-python3-runtime":  # source only: a pure-Python wheel built here
            cmd = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(cache), f"{name}=={version}"]
        else:
            cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:"]
            cmd += ["--python-version", "3.12", "--implementation", "cp", "-d", str(cache)]
            cmd += [arg for p in PLATFORMS for arg in ("--platform", p)] + [f"{name}=={version}"]
        subprocess.run(cmd, check=True)
    return sorted(cache.glob("*.whl"))


def keep_one_arch(library: bytes, keep_sm: int = KEEP_SM) -> tuple[bytes, int]:
    """``library`` (an ELF shared object) with the payload of every entry of its ``.nv_fatbin``
    section zeroed but the machine code for ``sm_<keep_sm>`` and the lowest PTX (which a newer GPU
    can compile); the headers stay, so the CUDA runtime still finds the kept entries where they
    were, and the zeros compress to nothing. Returns the bytes and how many were zeroed."""
    data = bytearray(library)
    (shoff,) = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x3A)

    def section(i: int) -> tuple:
        return struct.unpack_from("<IIQQQQIIQQ", data, shoff + i * shentsize)

    names = section(shstrndx)[4]
    fatbin = next(s for s in map(section, range(shnum)) if data[names + s[0] :].split(b"\0")[0] == b".nv_fatbin")
    pos, end = fatbin[4], fatbin[4] + fatbin[5]
    entries = []
    while pos < end:
        magic, _, header, size = struct.unpack_from("<IHHQ", data, pos)
        if magic != FATBIN_MAGIC:  # padding between the fatbins
            pos += 8
            continue
        p, stop = pos + header, pos + header + size
        while p < stop:
            kind, _, entry_header, padded = struct.unpack_from("<HHII", data, p)
            (sm,) = struct.unpack_from("<I", data, p + 28)
            entries.append((kind, sm, p + entry_header, padded))
            p += entry_header + padded
        pos = stop
    ptx = min((sm for kind, sm, _, _ in entries if kind == 1), default=None)
    zeroed = 0
    for kind, sm, start, size in entries:
        if (kind == 2 and sm == keep_sm) or (kind == 1 and sm == ptx):
            continue
        data[start : start + size] = bytes(size)
        zeroed += size
    if not any(kind == 2 and sm == keep_sm for kind, sm, _, _ in entries):
        raise ValueError(f"no sm_{keep_sm} machine code in this library's fatbin")
    return bytes(data), zeroed


def trim_warp(wheel: Path, whl_dir: Path, payload: Path, cache: Path) -> dict:
    """Warp's wheel without its two native libraries, examples and tests (a wheel of its own in
    ``whl_dir``), and its core library with one architecture (:func:`keep_one_arch`) as
    ``payload/warp/bin/warp.so.xz``. The CPU compiler library (``warp-clang.so``) is left out:
    Warp loads it only if present, and only its CPU device needs it; on CUDA, Warp compiles with
    NVRTC, which is in the core library."""
    drop = ("warp/bin/", "warp/examples/", "warp/tests/")
    out = whl_dir / wheel.name
    with zipfile.ZipFile(wheel) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            if info.filename.startswith(drop):
                continue
            body = src.read(info)
            if info.filename.endswith(".dist-info/RECORD"):  # the dropped files are not installed
                lines = body.decode().splitlines()
                body = "\n".join(x for x in lines if not x.startswith(drop)).encode() + b"\n"
            dst.writestr(info, body)
        core, zeroed = keep_one_arch(src.read("warp/bin/warp.so"))
    target = payload / "warp" / "bin" / "warp.so.xz"
    target.parent.mkdir(parents=True, exist_ok=True)
    # xz's strongest setting, with the x86 filter for machine code and a dictionary wider than the
    # default 64 MiB (the library repeats itself across its sections): 299 MB -> 55.7 MB. About 8
    # minutes of one core, so kept beside the wheels, by the library's hash.
    digest = hashlib.sha256(core).hexdigest()[:16]
    cached = cache / f"warp.so.{digest}.xz"
    if not cached.exists():
        lzma2 = {"id": lzma.FILTER_LZMA2, "preset": 9 | lzma.PRESET_EXTREME, "dict_size": 192 << 20}
        cached.parent.mkdir(parents=True, exist_ok=True)
        cached.write_bytes(lzma.compress(core, format=lzma.FORMAT_XZ, filters=[{"id": lzma.FILTER_X86}, lzma2]))
    shutil.copy2(cached, target)
    return {"wheel_bytes": out.stat().st_size, "core_bytes": len(core), "zeroed": zeroed, "xz": target.stat().st_size}


def stage(dest: Path, cache: Path) -> dict:
    """Everything the device needs, under ``dest``: this checkout's code, ``whl/`` (the wheels,
    Warp's trimmed) and ``payload/`` (files copied into the install's site folder as they are, or
    decompressed if they end in ``.xz``)."""
    wheels = download_wheels(cache)
    for sub in ("cmdp_rl", "configs", "lab", "experiments", "whl", "payload"):
        shutil.rmtree(dest / sub, ignore_errors=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for sub in ("cmdp_rl", "configs", "lab"):
        shutil.copytree(ROOT / sub, dest / sub, ignore=ignore)
    (dest / "experiments" / "speed").mkdir(parents=True)
    shutil.copy2(ROOT / "experiments" / "speed" / "gpu_figures.py", dest / "experiments" / "speed")
    whl, payload = dest / "whl", dest / "payload"
    whl.mkdir()
    report = {}
    for wheel in wheels:
        if wheel.name.startswith("warp_lang-"):
            report["warp"] = trim_warp(wheel, whl, payload, cache)
        else:
            shutil.copy2(wheel, whl)
    # env=safe_nav reads only the robots' MJCF files from Safety-Gymnasium (world.py: the package is
    # found, not imported); its 27 MB wheel is mostly textures. The installed package's files, then.
    import importlib.util

    found = importlib.util.find_spec("safety_gymnasium")
    if found is None or not found.submodule_search_locations:
        raise SystemExit("--stage reads the robots' models from Safety-Gymnasium: run `make setup-safety-gym`")
    source = Path(list(found.submodule_search_locations)[0])
    models = payload / "safety_gymnasium" / "assets" / "xmls"
    models.mkdir(parents=True)
    (payload / "safety_gymnasium" / "__init__.py").write_text('"""The robot models of Safety-Gymnasium 1.0.0."""\n')
    for robot in ("point", "car"):
        shutil.copy2(source / "assets" / "xmls" / f"{robot}.xml", models)
    report["bytes"] = {sub: _du(dest / sub) for sub in ("cmdp_rl", "configs", "lab", "whl", "payload")}
    return report


def split_for_two_calls(staged: Path, first: Path, second: Path, first_bytes: int) -> dict:
    """What ``stage`` gathered, as two calls' folders when it is too big for one: ``first`` has the
    code, the wheels but MuJoCo's and Warp's, and in ``parts/`` the first ``first_bytes`` of each
    compressed payload file; ``second`` has the code, every wheel and the payload, each compressed
    file's rest as ``<name>.part2``. The first call keeps its parts in the machine's /tmp
    (``--keep-parts``); the second, on the same machine while it is still warm, joins them
    (``--parts``)."""
    for folder in (first, second):
        shutil.rmtree(folder, ignore_errors=True)
        for sub in ("cmdp_rl", "configs", "lab", "experiments"):
            shutil.copytree(staged / sub, folder / sub)
        (folder / "whl").mkdir()
    for wheel in sorted((staged / "whl").glob("*.whl")):
        shutil.copy2(wheel, second / "whl")
        if not wheel.name.startswith(("mujoco", "warp_lang")):
            shutil.copy2(wheel, first / "whl")
    shutil.copytree(staged / "payload", second / "payload")
    for path in sorted((second / "payload").rglob("*.xz")):
        if path.stat().st_size <= first_bytes:
            continue
        data = path.read_bytes()
        head = first / "parts" / path.relative_to(second / "payload")
        head.parent.mkdir(parents=True, exist_ok=True)
        Path(f"{head}.part1").write_bytes(data[:first_bytes])
        Path(f"{path}.part2").write_bytes(data[first_bytes:])
        path.unlink()
    return {"first": _du(first), "second": _du(second)}


def _du(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


# --- on the device -----------------------------------------------------------------------------
class Budget:
    """Seconds left of the call's budget, and each item's share of what is left."""

    def __init__(self, seconds: float) -> None:
        self.start = time.monotonic()
        self.end = self.start + seconds

    def left(self) -> float:
        return self.end - time.monotonic()

    def elapsed(self) -> float:
        return time.monotonic() - self.start


class Results:
    """One JSON file per item under ``out``, written as soon as the item ends (or fails)."""

    def __init__(self, out: Path) -> None:
        self.out = out
        out.mkdir(parents=True, exist_ok=True)

    def write(self, name: str, data: dict, quiet: bool = False) -> None:
        (self.out / f"{name}.json").write_text(json.dumps(data, indent=1, default=str))
        if not quiet:
            say(f"wrote {name}.json")


def say(line: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {line}", flush=True)


def install(wheels: Path, payload: Path | None, site: Path, parts: Path | None = None) -> dict:
    """The carried wheels into ``site`` (pip, no index, no dependencies: each is named), then the
    payload's files (``.xz``: decompressed; ``.xz.part2``: joined after its ``.xz.part1`` under
    ``parts``, then decompressed); ``site`` goes first on ``sys.path``."""
    t0 = time.perf_counter()
    site.mkdir(parents=True, exist_ok=True)
    files = sorted(str(p) for p in wheels.glob("*.whl"))
    cmd = [sys.executable, "-m", "pip", "install", "-q", "--no-index", "--no-deps", "--no-compile"]
    cmd += ["--no-cache-dir", "--upgrade", "--target", str(site), *files]
    if files:
        subprocess.run(cmd, check=True)
    unpacked, problem = [], None
    for path in sorted(payload.rglob("*")) if payload else []:
        if not path.is_file():
            continue
        rel = path.relative_to(payload)
        data = path.read_bytes()
        if path.name.endswith(".xz.part2"):
            rel = rel.with_suffix("")
            head = (parts or Path("/nonexistent")) / f"{rel}.part1"
            if not head.exists():
                problem = (
                    f"{head} is missing: the first call's part of {rel} is gone (the machine was given back "
                    "between the two calls), so MuJoCo Warp cannot be installed"
                )
                continue
            data = head.read_bytes() + data
        target = site / rel.with_suffix("") if rel.suffix == ".xz" else site / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        if rel.suffix == ".xz":
            target.write_bytes(lzma.decompress(data))
        else:
            target.write_bytes(data)
        unpacked.append(str(rel))
    sys.path.insert(0, str(site))
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site), str(ROOT), os.environ.get("PYTHONPATH")]))
    importlib.invalidate_caches()
    out = {"wheels": [Path(f).name for f in files], "payload": unpacked, "seconds": time.perf_counter() - t0}
    return {**out, "problem": problem} if problem else out


def probe(device: str) -> dict:
    """Versions, the device, and whether each package the run needs imports (one line each)."""
    info: dict = {"python": sys.version.split()[0], "platform": platform.platform(), "cpus": os.cpu_count()}
    problems = {}
    for name in ("numpy", "torch", "tensordict", "torchrl", "hydra", "omegaconf", "pydantic", "gymnasium"):
        try:
            info[name] = getattr(importlib.import_module(name), "__version__", "?")
        except Exception as exc:  # noqa: BLE001  (recorded, and the run stops below)
            problems[name] = f"{type(exc).__name__}: {exc}"
    for name in ("mujoco", "warp", "mujoco_warp"):
        try:
            info[name] = getattr(importlib.import_module(name), "__version__", "?")
        except Exception as exc:  # noqa: BLE001  (recorded: the Warp items are then skipped)
            problems[name] = f"{type(exc).__name__}: {exc}"
    # TorchRL's C++ extension is built against one torch; our code uses none of it (no prioritised
    # replay). Whether it loads on this torch, in a child process in case loading it crashes:
    child = subprocess.run([sys.executable, "-c", "import torchrl._torchrl"], capture_output=True, text=True)
    info["torchrl_cpp_extension"] = (
        "loads" if child.returncode == 0 else (child.stderr.strip().splitlines() or ["?"])[-1]
    )
    info["problems"] = problems
    if "torch" in problems:
        return info
    import torch

    if device == "cuda":
        if not torch.cuda.is_available():
            problems["cuda"] = "torch sees no CUDA device"
        else:
            p = torch.cuda.get_device_properties(0)
            info["gpu"] = {
                "name": p.name,
                "capability": f"{p.major}.{p.minor}",
                "memory_gib": round(p.total_memory / 2**30, 1),
                "multiprocessors": p.multi_processor_count,
                "torch_cuda": torch.version.cuda,
            }
            smi = subprocess.run(
                ["nvidia-smi", "--query-gpu=name,driver_version,memory.total,clocks.max.sm", "--format=csv,noheader"],
                capture_output=True,
                text=True,
            )
            info["nvidia_smi"] = smi.stdout.strip() or smi.stderr.strip()
    info["problems"] = problems
    return info


def sync(device: str) -> None:
    import torch

    if device == "cuda":
        torch.cuda.synchronize()


def warm_kernels(device: str, tiny: bool) -> dict:
    """Compile (or load from Warp's cache) every kernel both tasks use, before any timing: Warp
    compiles all loaded modules before its first graph capture; here, in as many threads as there
    are cores (NVRTC runs outside the GIL)."""
    import torch
    import warp as wp

    from cmdp_rl.envs.safe_nav.env import SafeNavVecEnv

    wp.config.load_module_max_workers = os.cpu_count() or 1
    out: dict = {"workers": wp.config.load_module_max_workers}
    for task in TASKS:
        t0 = time.perf_counter()
        env = SafeNavVecEnv(task, 2, device=device, physics="mjwarp")
        env.reset(seed=0)
        env.step(torch.zeros(2, env.action_dim, device=device))
        sync(device)
        out[task] = time.perf_counter() - t0
        env.close()
        say(f"kernels for {task}: {out[task]:.1f} s")
    out["cache"] = str(wp.config.kernel_cache_dir)
    cache = Path(out["cache"])
    out["cache_mb"] = round(_du(cache) / 1e6, 1) if cache.exists() else None
    return out


def correctness(device: str, tiny: bool) -> dict:
    """Item 1: each task on the device against MuJoCo, each step from MuJoCo's state."""
    from cmdp_rl.envs.safe_nav.spec import nav_spec
    from lab.fidelity.physics_compare import compare_physics, tolerance_breaches
    from lab.fidelity.safe_nav_fidelity import steer

    steps, episode = (20, 10) if tiny else (200, 100)
    rows = {}
    for task in TASKS:
        t0 = time.perf_counter()
        out = compare_physics(task, 2, steps, steer, max_steps=episode, forced=True, device=device)
        out["breaches"] = tolerance_breaches(out, nav_spec(task).robot)
        out["within_tolerance"] = not out["breaches"]
        out["seconds"] = time.perf_counter() - t0
        rows[task] = out
        say(f"{task}: within tolerance: {out['within_tolerance']} {out['breaches']}")
    free = compare_physics("PointGoal1", 2, steps // 2, steer, device=device)  # the CPU test: < 2e-2 m
    free["within_2e-2_m"] = free["pos_max_diff"] < 2e-2
    rows["PointGoal1_free_running"] = free
    return rows


def memory_now(device: str) -> dict:
    import torch

    if device != "cuda":
        return {}
    import warp as wp

    free, _ = torch.cuda.mem_get_info()
    pool = wp.get_mempool_used_mem_current("cuda:0") if wp.is_mempool_enabled("cuda:0") else None
    return {"free": free, "warp_pool": pool, "torch": torch.cuda.memory_allocated()}


def env_row(task: str, n: int, device: str, max_steps: int, seconds: float) -> dict:
    """Item 2, one row: build and reset ``n`` worlds (the host places every layout), one step
    (records the step's graph at this N), then as many random-action steps as fit ``seconds``
    (at most ``max_steps``), then the physics graph alone replayed as often; memory from before
    the build to after the steps. All envs start together and their time limit is 1000 steps, so
    no reset falls in the timed window: these are rates of stepping, resets apart."""
    import torch

    from cmdp_rl.envs.safe_nav.env import SafeNavVecEnv

    dev = torch.device(device)
    gc.collect()
    before = memory_now(device)
    t0 = time.perf_counter()
    env = SafeNavVecEnv(task, n, device=dev, physics="mjwarp")
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    env.reset(seed=0)
    sync(device)
    reset = time.perf_counter() - t0
    gen = torch.Generator(device=dev).manual_seed(0)
    t0 = time.perf_counter()
    env.step(torch.rand(n, env.action_dim, generator=gen, device=dev) * 2 - 1)
    sync(device)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(3):
        env.step(torch.rand(n, env.action_dim, generator=gen, device=dev) * 2 - 1)
    sync(device)
    per_step = (time.perf_counter() - t0) / 3
    steps = max(5, min(max_steps, int(seconds / per_step)))
    actions = torch.rand(steps, n, env.action_dim, generator=gen, device=dev) * 2 - 1
    t0 = time.perf_counter()
    for a in actions:
        env.step(a)
    sync(device)
    dt = time.perf_counter() - t0
    worlds = env.worlds
    t0 = time.perf_counter()
    for _ in range(steps):
        worlds._replay("step", worlds._physics)
    sync(device)
    physics = time.perf_counter() - t0
    after = memory_now(device)
    row = {
        "task": task,
        "num_envs": n,
        "timed_steps": steps,
        "env_steps_per_s": n * steps / dt,
        "physics_steps_per_s": n * steps / physics,
        "ms_per_env_step": dt / steps * 1e3,
        "ms_per_physics_replay": physics / steps * 1e3,
        "build_s": build,
        "reset_s": reset,
        "host_place_ms_per_env": reset / n * 1e3,
        "first_step_s": first,
        "env_steps_since_reset": int(env.steps.max()),
        "overflow_worlds": int((worlds.data.overflow.numpy() != 0).sum()),
    }
    if before:
        row["device_bytes_per_world"] = (before["free"] - after["free"]) / n
        if before["warp_pool"] is not None:
            row["warp_bytes_per_world"] = (after["warp_pool"] - before["warp_pool"]) / n
        row["torch_bytes_per_world"] = (after["torch"] - before["torch"]) / n
    env.close()
    del env, worlds, actions
    gc.collect()
    if device == "cuda":
        torch.cuda.empty_cache()
    return row


def train_run(overrides: list[str], run_dir: Path) -> dict:
    """``train()`` of ``overrides`` into ``run_dir``: the whole call's seconds, the training's, and
    metrics.csv's per-iteration rows (steps/s, cumulative time, training return and cost)."""
    from cmdp_rl import train
    from cmdp_rl.config.run_config import compose_config

    t0 = time.perf_counter()
    result = train(compose_config(overrides), run_dir, echo=lambda line: say(f"  {line}"))
    wall = time.perf_counter() - t0
    with open(run_dir / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    keep = ("iteration", "steps", "sps", "time_s", "episode_return", "episode_cost", "lambda")
    return {
        "overrides": overrides,
        "wall_s": wall,
        "train_time_s": result["train_time_s"],
        "steps": result["steps"],
        "eval_return": result.get("episode_return"),
        "eval_cost": result.get("episode_cost"),
        "iterations": [{k: r[k] for k in keep if k in r} for r in rows],
    }


def training_speed(device: str, tiny: bool, left: float, place_ms: float | None) -> dict:
    """Item 3: ppo_lag on PointGoal1 at N = 4,096 (64 steps per env per iteration) for 1e6 steps
    (4 iterations; fewer if the budget is short), and the time to 1e7 extrapolated from it."""
    n, rollout, total = (8, 16, 256) if tiny else (4096, 64, 1_000_000)
    per_iter = n * rollout
    if not tiny and left < 90:  # about 15 s per iteration plus start-up, at a guess: two iterations
        total = 2 * per_iter
    overrides = [
        "env=safe_nav",
        "env.task=PointGoal1",
        "env.physics=mjwarp",
        f"env.num_envs={n}",
        f"device={device}",
        "algo=ppo_lag",
        f"rollout_steps={rollout}",
        f"total_steps={total}",
        "eval_episodes=2",
        "log_interval=1",
    ]
    with tempfile.TemporaryDirectory() as d:
        run = train_run(overrides, Path(d) / "run")
    sps = [float(r["sps"]) for r in run["iterations"]]
    steady = statistics.median(sps[1:] or sps)  # the first iteration pays for recording graphs
    target = 10_000_000
    iterations = math.ceil(target / per_iter)
    # Every env's episode ends at its time limit (1000 steps) at once, as all started together:
    # a wave of N layouts placed on the host per 1000 steps per env (none fell in the measured run).
    waves = (iterations * rollout) // 1000
    wave_s = waves * n * (place_ms or 0.0) / 1e3
    run.update(
        {
            "num_envs": n,
            "rollout_steps": rollout,
            "measured_steps": run["steps"],
            "steps_per_s_median_after_first": steady,
            "start_up_and_eval_s": run["wall_s"] - run["train_time_s"],
            "extrapolated_1e7": {
                "iterations": iterations,
                "training_s": iterations * per_iter / steady,
                "reset_waves": waves,
                "reset_waves_s": wave_s,
                "total_s": iterations * per_iter / steady + wave_s + run["wall_s"] - run["train_time_s"],
            },
        }
    )
    return run


def populations(device: str, tiny: bool, results: Results) -> dict:
    """Item 4: the population benchmark's together side (Reach1D torch preset, 64 envs per agent,
    3 iterations, ppo_lag, deploy.policy=last) at P = 64 and 256, and its layer timing."""
    from lab.bench.population_benchmark import layers, together

    sizes = (2, 4) if tiny else (64, 256)
    args = SimpleNamespace(envs=8 if tiny else 64, iterations=1 if tiny else 3, device=device, threads=1)
    args.final_policy = "last"
    out: dict = {"envs_per_agent": args.envs, "iterations": args.iterations, "rows": []}
    with tempfile.TemporaryDirectory() as d:
        for p in sizes:
            row = together(args, p, Path(d))
            out["rows"].append(row)
            say(f"P = {p}: {row['summed_steps_per_s']:,.0f} summed steps/s ({row['train_time_s']:.1f} s)")
            results.write("item4_population", {**out, "partial": True}, quiet=True)
    out["layers"] = layers(list(sizes), 256, 32, device)
    return out


def learning(device: str, tiny: bool, left: float, results: Results) -> dict:
    """Item 5: PointGoal1 ppo_lag, one seed, 2M steps (256 envs x 250 steps per iteration, 32
    iterations), evaluated on 10 stochastic episodes; ``python -m cmdp_rl`` in a child
    process, stopped at ``left`` s (:func:`child_run`)."""
    n, rollout, total, episodes = (4, 16, 128, 1) if tiny else (256, 250, 2_000_000, 10)
    overrides = [
        "env=safe_nav",
        "env.task=PointGoal1",
        "env.physics=mjwarp",
        f"env.num_envs={n}",
        f"device={device}",
        "algo=ppo_lag",
        f"rollout_steps={rollout}",
        f"total_steps={total}",
        "seed=0",
        f"eval_episodes={episodes}",
        "eval_deterministic=false",
        "log_interval=4",
    ]
    return child_run("item5_learning", overrides, left, results)


def many_worlds(device: str, tiny: bool, left: float, results: Results, out: Path) -> dict:
    """Item 6 (issue 53): the many-worlds preset (configs/experiment/safe_nav_gpu.yaml) on PointGoal1, one seed,
    for as many of its 1e8 steps as ``left`` s allow at the measured speed (the run's own step budget, so it ends
    with its deployment and evaluation); the run directory's config.yaml, metrics.csv and eval.json are copied
    under ``out/item6_run`` for the campaign's record (lab/bench/campaign.py)."""
    sps = 2_000 if tiny else 200_000  # item 3's steady rate on an H200, at a guess where it did not run
    steps = max(1, int((left - 120) * sps)) if not tiny else 8192  # start-up, evaluation and checkpoints: 120 s
    overrides = ["+experiment=safe_nav_gpu", f"device={device}", f"total_steps={min(steps, 100_000_000)}", "seed=0"]
    if tiny:
        overrides += ["env.num_envs=8", "eval_episodes=2", "env.max_steps=64"]
    return child_run("item6_many_worlds", overrides, left, results, keep=out / "item6_run")


def child_run(name: str, overrides: list[str], left: float, results: Results, keep: Path | None = None) -> dict:
    """``python -m cmdp_rl <overrides>`` in a child process, stopped at ``left`` s. Its metrics.csv is read every
    10 s and the item's JSON rewritten, so that a run cut short (here or by the call's limit) leaves its curve so
    far; ``keep``: a folder the run's config, metrics and evaluation are copied into."""
    out: dict = {"overrides": overrides, "status": "running"}
    with tempfile.TemporaryDirectory() as d:
        run_dir = Path(d) / "run"

        def read() -> None:
            if (run_dir / "metrics.csv").exists():
                with open(run_dir / "metrics.csv") as f:
                    out["iterations"] = list(csv.DictReader(f))
            if (run_dir / "eval.json").exists():
                out["eval"] = json.loads((run_dir / "eval.json").read_text())
            out["wall_s"] = time.perf_counter() - t0

        cmd = [sys.executable, "-m", "cmdp_rl", *overrides, f"hydra.run.dir={run_dir}"]
        t0 = time.perf_counter()
        child = subprocess.Popen(cmd, cwd=ROOT)
        while child.poll() is None and time.perf_counter() - t0 < left:
            time.sleep(min(10.0, max(0.1, left - (time.perf_counter() - t0))))
            read()
            results.write(name, out, quiet=True)
        if child.poll() is None:
            child.kill()
            child.wait()
            out["status"] = f"stopped after {left:.0f} s (the call's budget): no evaluation"
        else:
            out["status"] = "finished" if child.returncode == 0 else f"failed, exit {child.returncode}"
        read()
        if keep is not None:
            keep.mkdir(parents=True, exist_ok=True)
            for f in ("config.yaml", "metrics.csv", "eval.json"):
                if (run_dir / f).exists():
                    shutil.copy(run_dir / f, keep / f)
    return out


def run_item(results: Results, name: str, fn, *args) -> dict | None:
    """``fn(*args)`` written as ``name``.json, or its error, in one line and a traceback."""
    say(f"{name}: start")
    t0 = time.perf_counter()
    try:
        data = fn(*args)
        data = data if isinstance(data, dict) else {"value": data}
        data["item_seconds"] = time.perf_counter() - t0
        results.write(name, data)
        return data
    except Exception as exc:  # noqa: BLE001  (one item's failure must not cost the others)
        traceback.print_exc()
        results.write(
            name,
            {
                "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(),
                "seconds": time.perf_counter() - t0,
            },
        )
        say(f"{name}: FAILED: {type(exc).__name__}: {exc}")
        return None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--stage", type=Path, help="here: gather what the device needs into this folder, then stop")
    p.add_argument("--wheel-cache", type=Path, default=Path("/tmp/gpu_figures_wheels"))
    p.add_argument("--wheels", type=Path, help="install these wheels into --site first (the device)")
    p.add_argument("--payload", type=Path, help="files copied (.xz: decompressed) into --site after the wheels")
    p.add_argument("--site", type=Path, default=Path("/tmp/site"))
    p.add_argument("--split", type=Path, nargs=2, metavar=("FIRST", "SECOND"), help="with --stage: two calls' folders")
    p.add_argument("--first-bytes", type=int, default=48_000_000, help="with --split: the first call's share of Warp")
    p.add_argument("--keep-parts", type=Path, help="first of two calls: copy parts/ here (the machine's /tmp) first")
    p.add_argument("--parts", type=Path, help="second of two calls: where the first call kept its parts")
    p.add_argument("--out", type=Path, default=Path(os.environ.get("OUT", "outputs/gpu_figures")))
    p.add_argument("--device", default="cuda", choices=["cpu", "cuda"])
    p.add_argument("--budget-s", type=float, default=400.0, help="wall seconds for everything after the install")
    p.add_argument("--tiny", action="store_true", help="every item shrunk (a rehearsal on Warp's CPU device)")
    p.add_argument("--items", default="1,2,3,4,5", help="which items to run (6: the many-worlds preset, issue 53)")
    args = p.parse_args(argv)
    if args.stage:
        report = stage(args.stage, args.wheel_cache)
        if args.split:
            report["split"] = split_for_two_calls(args.stage, *args.split, args.first_bytes)
        print(json.dumps(report, indent=1))
        return 0
    if args.keep_parts:  # before anything that could fail: the second call needs these
        shutil.copytree(ROOT / "parts", args.keep_parts, dirs_exist_ok=True)
        say(f"kept {_du(args.keep_parts):,} bytes in {args.keep_parts}")
    results = Results(args.out)
    env: dict = {"argv": sys.argv, "date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())}
    if args.wheels:
        env["install"] = install(args.wheels, args.payload, args.site, args.parts)
        say(f"installed {len(env['install']['wheels'])} wheels in {env['install']['seconds']:.1f} s")
    budget = Budget(args.budget_s)
    env.update(probe(args.device))
    core = {k: v for k, v in env["problems"].items() if k not in ("mujoco", "warp", "mujoco_warp")}
    if core:
        env["refused"] = "the run's own packages do not import here: " + "; ".join(f"{k}: {v}" for k, v in core.items())
        results.write("env", env)
        say(env["refused"])
        return 1
    warp_problem = "; ".join(f"{k}: {v}" for k, v in env["problems"].items())
    if env.get("install", {}).get("problem"):
        warp_problem = env["install"]["problem"]
    items = {int(i) for i in args.items.split(",")}
    if not warp_problem and items & {1, 2, 3, 5}:
        try:
            env["kernels"] = warm_kernels(args.device, args.tiny)
        except Exception as exc:  # noqa: BLE001  (the Warp items are then skipped; item 4 still runs)
            traceback.print_exc()
            warp_problem = f"MuJoCo Warp does not run on {args.device}: {type(exc).__name__}: {exc}"
    if warp_problem:
        env["warp_refused"] = f"items 1, 2, 3 and 5 not run: {warp_problem}"
        say(env["warp_refused"])
    results.write("env", env)
    say(f"budget left {budget.left():.0f} s")
    place_ms = None
    if 1 in items and not warp_problem:
        run_item(results, "item1_correctness", correctness, args.device, args.tiny)
    if 2 in items and not warp_problem:
        sizes = (4, 16) if args.tiny else (1024, 4096, 16384)
        # What items 3 to 5 need at the least (about 60, 60 and 90 s) stays for them; a row is
        # skipped if placing its layouts on the host (measured on the smaller rows) and about
        # 12 s of stepping would not fit in the rest.
        reserve = 150 + (60 if 4 in items else 0)
        rows: list[dict] = []
        skipped: list[str] = []

        def item2() -> dict:
            for n in sizes:
                for task in TASKS:
                    place = [r["host_place_ms_per_env"] for r in rows if r["task"] == task]
                    needed = n * (place[-1] if place else 3.0) / 1e3 + 12
                    if not args.tiny and budget.left() - reserve < needed:
                        skipped.append(f"{task} N={n}: about {needed:.0f} s needed, {budget.left() - reserve:.0f} left")
                        say(f"skipped {skipped[-1]}")
                        continue
                    rows.append(env_row(task, n, args.device, 20 if args.tiny else 200, 4.0))
                    say(
                        f"{task} N={n}: {rows[-1]['env_steps_per_s']:,.0f} env steps/s, physics alone "
                        f"{rows[-1]['physics_steps_per_s']:,.0f}, {rows[-1]['reset_s']:.1f} s to place"
                    )
                    results.write("item2_env", {"rows": rows, "skipped": skipped, "partial": True})
            return {"rows": rows, "skipped": skipped}

        run_item(results, "item2_env", item2)
        place_rows = [r for r in rows if r["task"] == "PointGoal1" and r["num_envs"] >= min(sizes)]
        place_ms = statistics.median(r["host_place_ms_per_env"] for r in place_rows) if place_rows else None
    if 3 in items and not warp_problem:
        reserve3 = 100 + (60 if 4 in items else 0)  # items 4 and 5 at the least
        run_item(results, "item3_train", training_speed, args.device, args.tiny, budget.left() - reserve3, place_ms)
    if 4 in items:
        run_item(results, "item4_population", populations, args.device, args.tiny, results)
    if 5 in items and not warp_problem:
        left = budget.left() - 5
        if left < 30:
            results.write("item5_learning", {"skipped": f"{left:.0f} s left of the budget"})
        else:
            run_item(results, "item5_learning", learning, args.device, args.tiny, left, results)
    if 6 in items and not warp_problem:
        run_item(
            results, "item6_many_worlds", many_worlds, args.device, args.tiny, budget.left() - 5, results, args.out
        )
    say(f"done in {budget.elapsed():.0f} s of the {args.budget_s:.0f} s budget")
    return 0
