"""Evaluation: the paper's metrics on synthetic scenes with ground truth (:mod:`.synthetic`), and what
users get on their own panoramas, without ground truth (:mod:`.real`)."""
