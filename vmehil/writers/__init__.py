"""What the commands write and show: files written atomically (``files``), output paths
checked first (``output_paths``), progress bars (``progress``), 7-bit text (``ascii_text``)."""
