"""Reading a file that a user names as a policy, safely: a regular file of bounded size, opened without blocking. No
rospy.

    data = read_regular_file(path, max_bytes=MAX_FILE_BYTES, what='policy file')   # PolicyError: one line
"""
import os
import stat


class PolicyError(ValueError):
    """A file that is not a policy this package can use; the message is one line that says what is wrong."""


def size_text(n: int) -> str:
    """A size for a message: MiB from 1 MiB on, else bytes."""
    return f'{n / (1024 * 1024):.1f} MiB' if n >= 1024 * 1024 else f'{n:,} bytes'


def _a(what: str) -> str:
    return ('an ' if what[:1].lower() in 'aeio' or what.startswith('ONNX') else 'a ') + what


def shown(value) -> str:
    """A value from a file, for a message: short, never its bytes at length (a plain short name as it is)."""
    if isinstance(value, str) and len(value) <= 40 and value.replace('_', '').isalnum() and value.isascii():
        return value
    text = ascii(value)
    return text if len(text) <= 40 else text[:37] + '...'


def read_fd(fd: int, limit: int) -> bytes:
    """At most limit bytes from an open file descriptor, read a MiB at a time until its end."""
    chunks, left = [], limit
    while left > 0:
        chunk = os.read(fd, min(left, 1 << 20))
        if not chunk:
            break
        chunks.append(chunk)
        left -= len(chunk)
    return b''.join(chunks)


def read_regular_file(path: str, max_bytes: int, what: str = 'policy file') -> bytes:
    """The bytes of a regular file of at most max_bytes, opened without blocking and checked once open (a path
    swapped for a FIFO or a device between a check and the open is refused, never waited on)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise PolicyError(f'no {what} at {path}') from None
    except OSError as e:
        raise PolicyError(f'{path}: cannot open it: {e.strerror}') from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise PolicyError(f'{path} is not a file' if stat.S_ISDIR(st.st_mode) else
                              f'{path} is not a regular file (a FIFO, a device or a socket)')
        if st.st_size > max_bytes:
            raise PolicyError(f'{path} is {size_text(st.st_size)}: too large for {_a(what)} '
                              f'(at most {size_text(max_bytes)})')
        data = read_fd(fd, max_bytes + 1)
        if len(data) > max_bytes:
            raise PolicyError(f'{path} is too large for {_a(what)} (at most {size_text(max_bytes)})')
        return data
    except OSError as e:
        raise PolicyError(f'{path}: cannot read it: {e.strerror}') from None
    finally:
        os.close(fd)
