"""The loop to the rig: boards (:mod:`.board`: the interface and its registry; :mod:`.virtual`,
:mod:`.quanser`), the safety supervisor (:mod:`.supervisor`) and the real-time runner with its
logs (:mod:`.runner`)."""
