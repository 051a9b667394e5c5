"""The ``replicate`` command line: ``command`` parses the verb, each verb lives in a module of its own (``train``,
``evaluate``, ``train_general``, ``cover``, ``plan``, ``export``, ``act``, ``tune``, ``compare``, ``init``,
``animate``), and ``inputs`` reads what they share (a region, ``--set``, an output claimed before any work)."""

from replicate.toolkit.cli.command import main

__all__ = ["main"]
