"""The middle of the pipeline: the one line-session interface (`session`), the one generic
driver that moves bytes between a session and its link (`driver`), and the links that only
do IO (`link`, `serial_link`, `udp_link`), with the far end's bytes read on budget (`rx`)."""
