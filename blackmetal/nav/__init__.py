"""The navigation service: goals in, ``cmd_vel/nav`` out, through the gateway's arbiter (docs/navigation.md)."""
