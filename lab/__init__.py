"""Checkout-only lab code: benchmarks (``bench``), studies (``studies``) and fidelity checks (``fidelity``).

Not part of the wheel: it runs from a checkout, over the installed or checked-out ``cmdp_rl``. The scripts in
``experiments/`` are thin command lines over it, and the tests may import it."""
