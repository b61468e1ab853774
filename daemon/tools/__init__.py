"""The test tools, in a room apart from the service that runs on the robot: ``bench``
measures lunad against a minimal floor loop (``lunad bench``), ``soak`` runs it for hours
under injected faults and judges it (``lunad soak``). The service never imports them;
only their sub-commands do."""
