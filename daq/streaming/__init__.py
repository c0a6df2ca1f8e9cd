"""What moves over sockets: the ZeroMQ sample bus and the recorder process."""
