"""Agent settings that make a training run take seconds (tests of the machinery, not learning)."""

FAST_AGENT = {
    "updates_per_step": 0.1,
    "hidden": 32,
    "random_interactions": 3,
    "latent_updates_per_interaction": 2,
}
#: the same as ``sili train`` / ``sili sweep`` arguments
FAST_ARGS = [x for k, v in FAST_AGENT.items() for x in ("--set", f"{k}={v}")]
