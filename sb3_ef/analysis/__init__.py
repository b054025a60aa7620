"""Seeing and scoring what Ego-Foresight learned: predictions, saliency, mask scores, records, ENS and plots.
Submodules are imported on use, so that the callbacks come without pandas, matplotlib or rliable."""
