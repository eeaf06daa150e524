"""Network pieces shared by GRIP and the learned baselines: residual MLP blocks and shape
checks (``blocks``), loss terms on hand-object distances (``terms``)."""
