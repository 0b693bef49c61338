"""The project's own EEG devices (``registry.BUILTIN``, kind ``eeg_device``): the Muse over LSL, BrainFlow boards."""
