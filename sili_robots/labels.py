"""How the paper writes each method, for figures and the lines printed for people (a module of
its own so neither pulls in the other's libraries)."""

METHOD_NAMES = {
    "sili": "SILI",
    "oracle": "Oracle",
    "lili": "LILI",
    "stable": "Stable",
    "sac": "SAC",
    "smirl": "SMiRL",
}
