"""The project's own rules: layers, lint, types, the docs and the test layout."""
