"""Sub-commands of the ``slamlib`` console script.

Each module listed in :data:`COMMANDS` defines ``NAME`` (the sub-command), ``HELP`` (one line),
``add_arguments(parser)`` and ``main(args) -> int``. Modules are imported only when listed or run, so
``slamlib --help`` stays fast and a broken optional dependency only breaks its own command.
"""

COMMANDS = {
    "bench": "slamlib.commands.bench",
    "sim1d": "slamlib.commands.sim1d",
    "sim2d": "slamlib.commands.sim2d",
    "run": "slamlib.commands.run",
    "synth": "slamlib.commands.synth",
    "sweep": "slamlib.commands.sweep",
}


def parameter_default(function, name: str):
    """The default of ``function``'s parameter ``name``: an option's default read from the library function the
    command passes it to, so that each default is written once (CONTRIBUTING.md)."""
    import inspect

    return inspect.signature(function).parameters[name].default


def particles(text: str):
    """``--particles``'s value: ``auto`` (:data:`slamlib.slam3d.config.AUTO`: the count of the filter's mode,
    :meth:`slamlib.slam3d.config.FilterConfig.particle_count`) or a whole number, checked by the caller."""
    from slamlib.slam3d.config import AUTO

    return AUTO if text.strip().lower() == AUTO else int(text)


def tilt_sigma(text: str):
    """``--tilt-sigma``'s value: ``auto`` (:data:`slamlib.slam3d.config.AUTO`: the prior weighs the accelerometer by
    its own consistency), ``adaptive`` (:data:`slamlib.slam3d.config.ADAPTIVE`: by the gain a Kalman filter would
    give it, from that consistency, the tilt's walk and the map's hold) or a number of radians (0 = off), checked by
    the configuration."""
    from slamlib.slam3d.config import ADAPTIVE, AUTO

    word = text.strip().lower()
    return word if word in (AUTO, ADAPTIVE) else float(text)
