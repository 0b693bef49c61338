"""A lab's own nao-trainer plug-ins: the policy ``alternate`` and the EEG device ``tinyband``."""
