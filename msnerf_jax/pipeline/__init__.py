"""Applications: the one-command pipeline (`settings`: its options; `stages`: the table of
its stages; `run`: the driver; `renders`: its videos), the demo, and the videos of a styled
run along a camera path (`videos`)."""
