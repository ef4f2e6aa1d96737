"""Controllers that turn end-effector commands into joint motion (see Sawyer-Reach)."""
