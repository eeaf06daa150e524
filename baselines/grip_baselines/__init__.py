"""grip-bench baselines (GrabNet-, TOCH-, ManipNet-style and reference rows).

Lives in the top-level ``baselines/`` folder of the repository and is imported as
``grip_baselines`` so that it cannot collide with other installed packages.
"""
