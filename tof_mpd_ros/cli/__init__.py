"""The ``tof-mpd`` command line: thin argparse shells over the library."""
