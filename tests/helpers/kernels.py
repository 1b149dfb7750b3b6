"""Which SIMD kernels this process runs, and the settings under which this CPU runs another CPU's
(``make test-cpus``; docs/testing.md, "Other CPUs on this one").

torch, numpy and the two BLAS libraries each pick their kernels when they load, from the CPU's
features, and a sum or an exp can differ in its last bits from one pick to another. One environment
variable per library makes it pick as a lesser CPU would; each was checked to change what runs
(tests/test_kernels.py):

- ``ATEN_CPU_CAPABILITY``: torch's own kernels (elementwise, reductions, softmax, random draws):
  ``default``, ``avx2`` or ``avx512``, as ``torch.backends.cpu.get_cpu_capability()`` then reports;
- ``NPY_DISABLE_CPU_FEATURES``: numpy's dispatched loops (exp, log, arctan2, sin, tanh, ...): the
  targets it may not use, gone from numpy's dispatch list;
- ``OPENBLAS_CORETYPE``: OpenBLAS (numpy's and scipy's matmul): the core whose kernels it loads;
- ``MKL_CBWR``: oneMKL (torch's matmul, so every ``nn.Linear``): ``COMPATIBLE`` is its one branch
  that changed results on an AMD EPYC, which runs MKL's other branches as it does its default.

Run as ``python -m helpers.kernels SETTING... [-- PYTEST_ARGS]`` (with ``PYTHONPATH=tests``), it
reruns the tests marked ``cpu_kernels`` under each setting this CPU can run, then says how much of
each tolerance the largest difference used (helpers/tolerance.py); ``--fingerprint`` prints this
process's dispatch and a digest of each library's results (what tests/test_kernels.py compares).
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import NamedTuple

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
VARIABLES = ("ATEN_CPU_CAPABILITY", "NPY_DISABLE_CPU_FEATURES", "OPENBLAS_CORETYPE", "MKL_CBWR")
AVX512 = "X86_V4 AVX512_ICL AVX512_SPR"  # numpy 2.4's AVX-512 targets (X86_V4: AVX-512 F/CD/BW/DQ/VL)


class Setting(NamedTuple):
    stands_for: str
    env: dict[str, str]
    needs: tuple[str, ...] = ()  # CPU features (numpy's names) without which the setting is not this CPU's to run


SETTINGS = {
    "avx2": Setting(
        "an AVX2 CPU without AVX-512 (Intel Haswell to Comet Lake, AMD Zen 1 to 3)",
        {"ATEN_CPU_CAPABILITY": "avx2", "NPY_DISABLE_CPU_FEATURES": AVX512, "OPENBLAS_CORETYPE": "Haswell"},
        needs=("AVX2", "FMA3"),
    ),
    "sse4": Setting(
        "an x86-64-v2 CPU, no AVX (an old CPU, or a VM that hides AVX); MKL's compatible branch",
        {
            "ATEN_CPU_CAPABILITY": "default",
            "NPY_DISABLE_CPU_FEATURES": "X86_V3 " + AVX512,
            "OPENBLAS_CORETYPE": "Nehalem",
            "MKL_CBWR": "COMPATIBLE",
        },
    ),
    "blas": Setting(
        "this CPU's torch and numpy kernels with other BLAS kernels (OpenBLAS's Sandy Bridge, MKL's compatible branch)",
        {"OPENBLAS_CORETYPE": "Sandybridge", "MKL_CBWR": "COMPATIBLE"},
    ),
}


def openblas_core() -> str:
    """The core whose kernels numpy's OpenBLAS loaded (``"unknown"`` for a numpy built on another BLAS)."""
    for lib in sorted((Path(np.__file__).parent.parent / "numpy.libs").glob("libscipy_openblas*")):
        handle = ctypes.CDLL(str(lib))  # numpy has it loaded already: the same library, the same state
        for name in ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename", "openblas_get_corename"):
            get = getattr(handle, name, None)
            if get is not None:
                get.restype = ctypes.c_char_p
                return get().decode()
    return "unknown"


def cpu_features() -> dict[str, bool]:
    from numpy._core._multiarray_umath import __cpu_features__

    return __cpu_features__


def dispatch() -> dict:
    """What this process runs: torch's kernel level, numpy's dispatched targets, OpenBLAS's core, MKL's branch."""
    import torch
    from numpy._core._multiarray_umath import __cpu_dispatch__

    return {
        "torch": torch.backends.cpu.get_cpu_capability(),
        "numpy": [t for t in __cpu_dispatch__ if cpu_features()[t]],
        "openblas": openblas_core(),
        "mkl_cbwr": os.environ.get("MKL_CBWR", "AUTO"),
    }


def fingerprint() -> dict[str, str]:
    """A digest of each library's results on fixed inputs: kernels that round differently give another digest."""
    import torch

    def digest(*arrays) -> str:
        h = hashlib.sha256()
        for a in arrays:
            h.update(np.ascontiguousarray(a.numpy() if isinstance(a, torch.Tensor) else a).tobytes())
        return h.hexdigest()[:16]

    rng = np.random.default_rng(0)
    x, y = rng.normal(size=100_003), rng.normal(size=100_003)  # long: every vector loop, and a tail
    a, b = rng.normal(size=(37, 61)), rng.normal(size=(61, 29))
    t, u = torch.from_numpy(x.astype(np.float32)), torch.from_numpy(y.astype(np.float32))
    gen = torch.Generator().manual_seed(0)
    return {
        "torch": digest(
            torch.exp(t),
            torch.tanh(t),
            torch.nn.functional.softplus(t),
            torch.atan2(t, u),
            t.abs() ** 1.7,
            t.sum(),
            torch.log_softmax(t, 0),
            torch.randn(1000, generator=gen),
        ),
        "numpy": digest(np.exp(x), np.log(np.abs(x)), np.arctan2(y, x), np.tanh(x), np.sin(x.astype(np.float32))),
        "openblas": digest(a @ b, a.astype(np.float32) @ b.astype(np.float32)),
        "mkl": digest(torch.from_numpy(a.astype(np.float32)) @ torch.from_numpy(b.astype(np.float32))),
    }


def environment(setting: str | None) -> dict[str, str]:
    """This process's environment with this CPU's own kernels (``None``) or ``setting``'s."""
    env = {k: v for k, v in os.environ.items() if k not in VARIABLES}
    return {**env, **(SETTINGS[setting].env if setting else {})}


def runnable(setting: str) -> bool:
    return all(cpu_features().get(f, False) for f in SETTINGS[setting].needs)


def probe(setting: str | None) -> dict:
    """``--fingerprint`` run in a new process with this CPU's own kernels (``None``) or ``setting``'s."""
    out = subprocess.run(
        [sys.executable, "-m", "helpers.kernels", "--fingerprint"],
        cwd=ROOT,
        env={**environment(setting), "PYTHONPATH": str(ROOT / "tests")},
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout)


def moved(own: dict, other: dict) -> set[str]:
    """The libraries whose kernels ``other`` (a :func:`probe`) picks differently from ``own``: as they
    report it, and for MKL, which reports nothing, its branch (COMPATIBLE is not the one it picks on a
    CPU with AVX2)."""
    libs = {lib for lib in ("torch", "numpy", "openblas") if other["dispatch"][lib] != own["dispatch"][lib]}
    if other["dispatch"]["mkl_cbwr"] != own["dispatch"]["mkl_cbwr"] and cpu_features()["AVX2"]:
        libs.add("mkl")
    return libs


def _margins(path: Path) -> dict[str, tuple[float, str]]:
    """Each tolerance's largest share used in a margins file (helpers/tolerance.py), and the test that used it."""
    worst: dict[str, tuple[float, str]] = {}
    if path.exists():
        for line in path.read_text().splitlines():
            r = json.loads(line)
            if r["share"] > worst.get(r["tolerance"], (-1.0, ""))[0]:
                worst[r["tolerance"]] = (r["share"], r["test"])
    return worst


def main(argv: list[str]) -> int:
    if argv == ["--fingerprint"]:
        print(json.dumps({"dispatch": dispatch(), "fingerprint": fingerprint()}))
        return 0
    names, pytest_args = (argv[: argv.index("--")], argv[argv.index("--") + 1 :]) if "--" in argv else (argv, [])
    failed, seen, own = [], {}, probe(None)
    for name in names or list(SETTINGS):
        if not runnable(name):
            print(f"== {name}: skipped, this CPU lacks {' and '.join(SETTINGS[name].needs)}", flush=True)
            continue
        if not moved(own, probe(name)):
            print(f"== {name}: skipped, this CPU's own kernels already (make test ran them)", flush=True)
            continue
        print(f"== {name}: {SETTINGS[name].stands_for}", flush=True)
        print("   " + " ".join(f"{k}={v!r}" for k, v in SETTINGS[name].env.items()), flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            env = {**environment(name), "CMDP_RL_MARGINS": str(Path(tmp) / "margins.jsonl")}
            cmd = [sys.executable, "-m", "pytest", "tests", "-m", "cpu_kernels and not heavy", *pytest_args]
            if subprocess.run(cmd, cwd=ROOT, env=env).returncode != 0:
                failed.append(name)
            seen[name] = _margins(Path(tmp) / "margins.jsonl")
    print("\nlargest share of each tolerance used (1.0: at the limit)")
    for tol in sorted({t for worst in seen.values() for t in worst}):
        cells = [f"{n} {seen[n][tol][0]:.2g}" for n in seen if tol in seen[n]]
        print(f"  {tol}: {', '.join(cells)}")
    print(f"\nfailed under: {', '.join(failed)}" if failed else "\nevery setting passed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
