"""Pieces shared by both algorithms: replay buffer, augmentation, layers, schedules, callbacks."""
