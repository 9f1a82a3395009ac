"""Commands around a run: ``terrain info``'s report, previews, synthetic surveys.

The top layer, beside ``pipeline.cli`` and ``pipeline.api``.
"""
