"""What a user touches: the command line (``cli``), ``cover`` (any lake file), ``export`` and ``act``,
``animate`` and ``plots``, and the PettingZoo environment. Imports every wing below it, never ``pipeline``."""
