"""Unit tests: ``unit/<package>/test_<module>.py`` holds the tests of ``blackmetal/<package>/<module>.py`` (fast unless marked)."""
