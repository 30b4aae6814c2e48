"""Every output protocol usb2rc speaks, registered: read the output registry here.

Each protocol's package declares its registry row, its own config keys and its build
function in its `output` module (`usb2rc.protocols.<name>.output`), which registers them when
it is imported; the imports below are the one place that lists the protocols, in the order
the registry lists them (the config's messages, `usb2rc decode --protocol`). A protocol added
later is its package and one line here.

The registry itself is `usb2rc.protocols.registry`: `PROTOCOLS` (name → `OutputProtocol`),
`protocol(name)`, `option_keys()`, `protocol_aliases()`, `build(context)`. Read through this
module, it holds every protocol; the config file reader, the daemon and the commands that
describe or decode an output (`check`, `icd`, `decode`) read it here.
"""

# Each import registers its protocol's row, in this order.
# isort: off
from usb2rc.protocols.c2_16b.output import C2_16B  # noqa: F401
from usb2rc.protocols.sumd.output import SUMD  # noqa: F401
from usb2rc.protocols.crsf.output import CRSF  # noqa: F401
from usb2rc.protocols.sbus.output import SBUS  # noqa: F401
from usb2rc.protocols.ibus.output import IBUS  # noqa: F401
from usb2rc.protocols.mavlink.output import MAVLINK  # noqa: F401

# isort: on
from usb2rc.protocols.registry import (
    PROTOCOLS,
    OutputProtocol,
    build,
    option_keys,
    protocol,
    protocol_aliases,
)

__all__ = ["PROTOCOLS", "OutputProtocol", "build", "option_keys", "protocol", "protocol_aliases"]
