"""Seeing and scoring what Ego-Foresight learned: open-loop predictions, saliency, agent-mask scores,
evaluation records, efficiency-normalised scores, rliable metrics and plots.

Submodules are imported on use so that training code can import the callbacks without pulling pandas,
matplotlib or rliable (the ``sb3-ef[analysis]`` extra).
"""
