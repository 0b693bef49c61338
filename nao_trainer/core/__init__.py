"""The pure core: task, MDP, engagement maths, user models, simulation, Q-learning. No I/O here."""
