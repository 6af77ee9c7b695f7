"""The command lines: `launch` (`launch`: roslaunch's argv), `launcher` (`tool`: the subcommand table), introspection, `launcher check`, `launcher doctor`, completion."""
