"""``bringup_check``: the first-power checks a builder runs on the Pi (real-robot.md s. 7)."""
