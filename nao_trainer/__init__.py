"""nao-trainer: personalised robot-assisted cognitive training (NAO + Muse + Q-learning)."""
__version__ = "0.1.0"
