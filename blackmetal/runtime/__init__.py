"""What every blackmetal process shares: settings, Zenoh setup and edge, error reports, signals, the process harness."""
