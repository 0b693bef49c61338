"""EEG adapters: LSL streams (Muse), markers, a simulated Muse, and the published recordings."""
