"""The ground every wing stands on: typed parameters (``schema`` declares a section, ``sections`` and ``studies``
hold them, ``params`` reads ``params.yaml``), files written atomically and read back (``artifacts``), outputs
claimed for a command's length (``outputs``), and the executor that runs jobs in local processes or on Ray
(``executor``). Imports no other wing."""
