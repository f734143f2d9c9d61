"""The simulated Black Metal robot: pure physics (``physics``), a TCP server speaking the real protocol
(``server``), an in-memory connector for tests (``memory``), its Zenoh edge and the ``blackmetal sim`` command."""
