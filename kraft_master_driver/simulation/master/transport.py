# Copyright 2026 kraft_master_driver contributors
# Licensed under the Apache License, Version 2.0
"""
The simulated device's port: a pseudo-terminal, or a TCP server reached as socket://.

The pty sits behind a stable symlink, so that it can be unplugged and replugged as a USB
serial adapter can. TCP serves on 127.0.0.1 the way a serial device server carries a serial
line over a network. A pty passes every byte through a kernel worker thread, which a busy
machine can leave waiting for seconds; loopback TCP has none.

Only the simulator's serving thread calls these, once start() has returned. Whenever the
host's end closes, on_hangup() is called: what was in flight to or from it is lost.
"""
import os
import shutil
import socket
import tempfile
import tty

TRANSPORTS = ('pty', 'tcp')
READ_SIZE = 4096
PROC_FD = '/proc/{pid}/fd/{fd}'


class _Transport:
    """What both transports share: the host's end as a descriptor, read and written raw."""

    listener = None  # a socket to accept hosts on, if the transport has one

    def __init__(self, on_hangup):
        """Call on_hangup() whenever the host's end closes."""
        self._on_hangup = on_hangup
        self.port = None  # what the host opens; None until start()
        self.host = None  # the host's end: a pty master or an accepted connection

    def write(self, data):
        """Write to the host; return False when unplugged or its buffer is full."""
        if self.host is None:
            return False
        try:
            written = os.write(self.host, data)
        except OSError:
            written = 0
        return written == len(data)


class PtyTransport(_Transport):
    """A pseudo-terminal in raw mode behind a symlink in a temporary directory."""

    def __init__(self, on_hangup):
        """Call on_hangup() whenever the pty closes."""
        super().__init__(on_hangup)
        self._slave = None
        self._directory = None

    def start(self):
        """Create the symlink's directory and open the pty; return the symlink."""
        self._directory = tempfile.mkdtemp(prefix='kraft_master_sim_')
        self.port = os.path.join(self._directory, 'tty')
        self.plug()
        return self.port

    def read(self):
        """Return the bytes the host sent (b'' when none, or no host has the slave open)."""
        try:
            return os.read(self.host, READ_SIZE)
        except OSError:
            return b''

    def plug(self):
        """Open a new pty in raw mode and point the port symlink at its slave."""
        self.unplug()
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        # Our own slave descriptor keeps the pty (and its raw mode) alive between host opens.
        self.host, self._slave = master, slave
        # Link through /proc where there is one: a link left behind by a killed simulator then
        # dangles, instead of leading a reconnecting driver to whichever pty gets the same
        # /dev/pts number next.
        target = PROC_FD.format(pid=os.getpid(), fd=slave)
        if not os.path.exists(target):
            target = os.ttyname(slave)
        staging = self.port + '.new'
        os.symlink(target, staging)
        os.replace(staging, self.port)

    def unplug(self):
        """Close the pty (the host sees a hangup), drop what was in flight, remove the link."""
        for fd in (self.host, self._slave):
            if fd is not None:
                os.close(fd)
        self.host = self._slave = None
        self._on_hangup()
        if self.port is not None and os.path.lexists(self.port):
            os.unlink(self.port)

    def stop(self):
        """Unplug and remove the temporary directory."""
        self.unplug()
        if self._directory is not None:
            shutil.rmtree(self._directory, ignore_errors=True)
            self._directory = None
        self.port = None


class TcpTransport(_Transport):
    """A TCP server on 127.0.0.1 that serves one host at a time; the port a socket:// URL."""

    def __init__(self, on_hangup):
        """Call on_hangup() whenever a host's connection closes."""
        super().__init__(on_hangup)
        self._port_number = 0  # chosen by the system at the first start()

    def start(self):
        """Start serving; return the URL."""
        self.plug()
        self.port = f'socket://127.0.0.1:{self._port_number}'
        return self.port

    def read(self):
        """Return the bytes the host sent; b'' when it has gone (the connection is closed)."""
        try:
            data = os.read(self.host, READ_SIZE)
        except OSError:
            data = b''
        if not data:
            self._drop_host()  # the host closed or reset its connection
        return data

    def plug(self):
        """Serve TCP on 127.0.0.1, on the port served before if any (unplugs first)."""
        self.unplug()
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(('127.0.0.1', self._port_number))
        listener.listen(1)
        listener.setblocking(False)
        self._port_number = listener.getsockname()[1]
        self.listener = listener

    def accept(self):
        """Take a host that connects; refuse a second one while the first is served."""
        try:
            connection, _address = self.listener.accept()
        except OSError:
            return
        if self.host is not None:
            connection.close()
            return
        connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        connection.setblocking(False)
        self.host = connection.detach()

    def unplug(self):
        """Stop serving TCP (a connected host sees the connection closed)."""
        self._drop_host()
        if self.listener is not None:
            self.listener.close()
            self.listener = None

    def stop(self):
        """Stop serving."""
        self.unplug()
        self.port = None

    def _drop_host(self):
        """Close the connection to the host; drop what was in flight."""
        if self.host is not None:
            os.close(self.host)
            self.host = None
        self._on_hangup()


def make_transport(name, on_hangup):
    """Return the transport called `name` (one of TRANSPORTS)."""
    if name not in TRANSPORTS:
        raise ValueError(f'transport must be one of {", ".join(TRANSPORTS)}, got {name!r}')
    return TcpTransport(on_hangup) if name == 'tcp' else PtyTransport(on_hangup)
