"""The one lock around native code that is not thread-safe (see :data:`NATIVE_CALLS`)."""

from __future__ import annotations

import threading

#: Compiled controllers and the plant's step run native code whose memory management
#: (CasADi's generated checkout/release and HPIPM's workspaces) keeps state shared by every
#: function loaded from one library, unguarded: two threads in it at once corrupt the heap
#: ("double free"); controllers of one problem share its Functions, so an MPC's solves
#: take this lock (``MpcController.step``), as the plant's step does in a flight. CasADi's
#: symbolic core is not thread-safe either: a controller or the plant's step Function is
#: built under this lock too. One flight at a time steps through
#: native code; the threads executor still overlaps everything else (LLM waits, rendering,
#: logging), also during an NMPC solve, which runs with the interpreter's lock released
#: (``control.codegen.NativeCall``). (The Riccati QP solver itself is reentrant; HPIPM's
#: path and CasADi's checkout are not.)
#: Re-entrant: a caller already holding it (building a controller, say) may call on.
NATIVE_CALLS = threading.RLock()
