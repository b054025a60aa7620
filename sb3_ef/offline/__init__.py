"""Ego-Foresight without RL: robot-video datasets, offline pretraining, open-loop prediction and warm starts."""
