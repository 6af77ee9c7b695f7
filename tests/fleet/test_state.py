

def test_over_limit_is_said_in_the_readmes_units():
    """The limit as the user wrote it (500MB is decimal, 512MiB binary), the measured use in decimal units: one
    formatter for `launcher status`'s OVER LIMIT column and /diagnostics (it once said 476.8 MB for 500MB)."""
    from launcher.fleet.state import over_limit_text
    assert over_limit_text({"memory_limit": 500_000_000}, None, 612_345_678) == "memory_limit 500MB (uses 612.3MB)"
    assert over_limit_text({"memory_limit": 512 << 20}, None, None) == "memory_limit 512MiB (uses ?)"
    assert over_limit_text({"cpu_limit": 0.5}, 0.75, None) == "cpu_limit 0.5 cores (uses 0.75)"
