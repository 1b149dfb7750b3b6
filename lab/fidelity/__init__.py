"""Fidelity checks: ``safe_nav_fidelity`` (the batched navigation tasks against Safety-Gymnasium) and
``physics_compare`` (``env.physics=mjwarp`` against ``mujoco``, per step and per episode)."""
