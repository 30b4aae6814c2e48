from usb2rc.cli import main

raise SystemExit(main())
