"""An example grip-bench plug-in (``pyproject.toml`` declares its entry points).

- ``method``: ``wrist-follow``, the input wrists with finger poses learned from the
  training split (a grasping mean near the object, a free mean away from it);
- ``metric``: ``tip_dist``, the fingertips' mean distance to the object's surface on held
  frames;
- ``tables``: ``example_wrist_follow.toml``, the method beside ``gt`` and ``mean-pose``.

Nothing here is imported by grip-bench except through the entry points.
"""
