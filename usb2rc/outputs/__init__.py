"""One module per output protocol: its channels, as the protocol names them, evaluated from
the node table's frames once a tick.

An output is three pieces, and every protocol (SUMD now; CRSF, SBUS, MAVLink next) has the
same shape:

- the sans-IO wire codec, `usb2rc.protocol.<name>` (values → bytes → values, its scaling);
- the sans-IO line session, `usb2rc.session` (`SumdSession`), driven by the shared scheduler
  (`usb2rc.scheduler`: one thread per output, one tick per period);
- `usb2rc.outputs.<name>`: the output's channels, from the typed channel references of the
  config to wire values and the frame's failsafe flag (`SumdChannels.evaluate(frames)`).

`usb2rc.daemon` only wires them together.
"""
