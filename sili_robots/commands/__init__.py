"""Sub-commands of the ``sili`` command line, one module each."""
