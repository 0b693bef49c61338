"""Every policy a live session can follow (``ports.Policy``): fixed ones, learned user-specific ones
and the personalised pipeline; ``policies.factory.make_policy`` builds the one a study names."""
