"""The live session: typed study configuration, dialogue, behaviors, the state machine and its record."""
