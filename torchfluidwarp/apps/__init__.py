"""The applications over the library: the command line (:mod:`~torchfluidwarp.apps.cli`), the one animation
pipeline it shares with the studio (:mod:`~torchfluidwarp.apps.animate`), and the browser studio
(:mod:`~torchfluidwarp.apps.studio`, ``pip install torchfluidwarp[studio]``). They call the library and hold no
numerics of their own; nothing in the library imports them."""
