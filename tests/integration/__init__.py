"""Integration tests: real processes and Zenoh sessions on loopback; every test here is ``integration`` and ``slow``."""
