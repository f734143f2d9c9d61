"""The Black Metal gateway: robot link, wire protocol, safety, Zenoh edge, and the simulated robot."""
