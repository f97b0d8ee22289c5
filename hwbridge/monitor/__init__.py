"""``hwbridge monitor``: a live terminal view of the running bridge (:mod:`.model` gathers,
:mod:`.view` draws)."""
