"""Language field and language-guided localisation (paper section III, opening).

Public API (imported lazily). The language *field* itself lives in
:mod:`neoedit.fields.language`, beside the radiance field, so scenes store it without
importing this package (no ``scene`` <-> ``language`` cycle):

* :func:`train_language` / :class:`LanguageTrainConfig`: distil a 2-D teacher into L(x).
* :func:`query_scene` / :class:`QueryConfig`: prompt -> :class:`QueryResult` (oriented box).
* :func:`relevancy`, :func:`load_text_encoder`, :class:`TextEncoderSpec`.
"""

from __future__ import annotations

from neoedit.utils.lazy import lazy_exports

_EXPORTS = {
    "train_language": "training",
    "LanguageTrainConfig": "training",
    "query_scene": "localize",
    "localize": "localize",
    "QueryConfig": "localize",
    "QueryResult": "localize",
    "NoMatch": "localize",
    "relevancy": "relevancy",
    "split_prompts": "relevancy",
    "load_text_encoder": "text",
    "TextEncoderSpec": "text",
}

__all__ = sorted(_EXPORTS)


__getattr__ = lazy_exports(__name__, _EXPORTS)
