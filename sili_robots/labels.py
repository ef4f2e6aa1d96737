"""How results are named and grouped for people: the figures, `sili runs` and the verdict share
them (a module of its own so none pulls in another's libraries)."""

#: how the paper writes each method
METHOD_NAMES = {
    "sili": "SILI",
    "oracle": "Oracle",
    "lili": "LILI",
    "stable": "Stable",
    "sac": "SAC",
    "smirl": "SMiRL",
}

#: what sets one variant of a task's runs apart from another: one curve, one row of `sili runs`
#: (two versions of a task are never averaged together)
VARIANT_KEYS = (
    "method",
    "profile",
    "config_beta",
    "beta_scheduled",
    "controller",
    "task_args",
    "latent",
    "task_id",
)
