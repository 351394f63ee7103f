"""The message bus every role uses: the :class:`~protocols.bus.interface.Bus` interface, its
Zenoh and in-memory implementations, Zenoh settings and the rendezvous port."""
