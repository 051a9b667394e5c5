"""The ground every wing stands on: typed parameters (``params``), files written atomically and read back
(``artifacts``), and the executor that runs jobs in local processes or on Ray (``executor``). Imports no other wing."""
