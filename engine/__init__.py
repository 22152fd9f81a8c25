"""vgr engine: recipes, DAG, plugin manager, zenoh bus, codecs, runner, recorder, replay and CLI.

Import packages are ``engine`` (this) and ``plugins`` (built-in stages); the distribution and the
command are ``vgr``.
"""

__version__ = "0.1.0"
