"""Recordings: the MCAP format of a run (mcapfmt, written by mcaprecords and mcapwriter, read by mcapread,
repaired by mcaprepair, its 3D scene by mcapscene) and the recorder's parts (recording_pipeline,
recording_files, recordings_library)."""
