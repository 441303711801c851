"""The parts of `leadthrough view` beyond the bus's own channels: the arm's forward kinematics
and its Foxglove 3D messages (:mod:`.arm`), and a self-contained page a plain browser opens
(:mod:`.page_server`, ``index.html``, ``live_view.js``)."""
