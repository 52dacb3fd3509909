"""The launch files shipped with palpate, installed as the data package `palpate.launch_files`."""
