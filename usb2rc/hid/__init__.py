"""Input: HID devices found and read, each decoded by its own report descriptor (hidapi,
replayed recordings, hot-plug), one reader thread per device publishing records."""
