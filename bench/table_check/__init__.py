"""The turntable check (paper section 5.1): estimate the observable black-box combinations, from a log,
and report them."""
