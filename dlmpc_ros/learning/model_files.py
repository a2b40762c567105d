"""What every model file shares, without torch: the kinds of model, the error a missing or
corrupt file raises, and how to make it again (so that nodes that load no torch model can
say so in the same words)."""

from __future__ import annotations

#: Model kinds and what they are called in messages.
KINDS = {'vae': 'VAE estimator', 'kmap': 'K-to-angles map', 'mprnn': 'MP-RNN',
         'response': 'steady-response predictor'}


class ModelFileError(RuntimeError):
    """A model file is missing, unreadable, of the wrong kind or of another schema."""


def regenerate_hint(kind: str) -> str:
    return f'regenerate it with `dlmpc-train {kind}` (see models/MODEL_CARD.md)'
