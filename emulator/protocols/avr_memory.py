"""An Arduino Mega's ATmega2560 memories, as its bootloader can change and read them.

256 KiB of flash in 256-byte pages, 4 KiB of EEPROM and the lock byte, with the chip's rules:
flash bits only go from 1 to 0 when a page is written, so a page holds what was written to it
only if it was erased first; the lock bits the Mega ships with keep the bootloader from writing
its own section. No file I/O here: whoever keeps the flash in a file asks which pages changed.
"""

FLASH_SIZE = 256 * 1024
EEPROM_SIZE = 4 * 1024
PAGE_SIZE = 256  # SPM_PAGESIZE: the flash is erased and written a page at a time
ERASED = 0xFF
# The boot section's start with the Mega's high fuse 0xD8 (BOOTSZ=00: 4096 words). Its lock byte
# 0x0F forbids SPM to write there, so the bootloader cannot overwrite itself.
BOOT_SECTION = FLASH_SIZE - 8 * 1024
# The lock byte as the chip reads it back: 0x0F as burnt, its two unused bits read as 1.
SHIPPED_LOCK = 0xCF
BLB01 = 0x04  # programmed (0): SPM may not write the application section either
BLB_MASK = 0x3C  # the boot lock bits SPM can program (LB1/LB2 need a programmer)


class FlashImageError(ValueError):
    """A flash image that is not this chip's (the caller did wrong)."""


class BoardMemory:
    """The printer's memories: they live as long as the printer does, across resets."""

    def __init__(self, flash: bytes | None = None) -> None:
        if flash is not None and len(flash) != FLASH_SIZE:
            raise FlashImageError(
                f"a flash image of {len(flash)} bytes; an ATmega2560's is {FLASH_SIZE} "
                f"({FLASH_SIZE // 1024} KiB)"
            )
        self.flash = bytearray(flash) if flash is not None else bytearray([ERASED]) * FLASH_SIZE
        self.eeprom = bytearray([ERASED]) * EEPROM_SIZE
        self.lock = SHIPPED_LOCK
        self._changed: dict[int, None] = {}  # pages changed since take_changed_pages(), in order

    # -- flash -----------------------------------------------------------------------------
    def _writable(self, page: int) -> bool:
        if page * PAGE_SIZE >= BOOT_SECTION:
            return False
        return bool(self.lock & BLB01)

    def erase_page(self, address: int) -> None:
        """boot_page_erase: the page holding byte `address` reads 0xFF again."""
        page = address % FLASH_SIZE // PAGE_SIZE
        if self._writable(page):
            start = page * PAGE_SIZE
            self.flash[start:start + PAGE_SIZE] = bytes([ERASED]) * PAGE_SIZE
            self._changed[page] = None

    def write_page(self, address: int, buffer: bytes) -> None:
        """boot_page_write of the page buffer to the page holding byte `address`: each bit
        already 0 stays 0, as flash cells only lose charge when written."""
        if len(buffer) != PAGE_SIZE:
            raise ValueError(f"a page buffer is {PAGE_SIZE} bytes, not {len(buffer)}")
        page = address % FLASH_SIZE // PAGE_SIZE
        if self._writable(page):
            start = page * PAGE_SIZE
            old = self.flash[start:start + PAGE_SIZE]
            self.flash[start:start + PAGE_SIZE] = bytes(a & b for a, b in zip(old, buffer))
            self._changed[page] = None

    def read_flash(self, address: int, size: int) -> bytes:
        """`size` bytes from byte `address`, the address wrapping at the end of the flash."""
        return bytes(self.flash[(address + i) % FLASH_SIZE] for i in range(size))

    @property
    def has_changed_pages(self) -> bool:
        return bool(self._changed)

    def take_changed_pages(self) -> list[int]:
        """The numbers of the pages changed since the last call, in the order they changed."""
        pages = list(self._changed)
        self._changed.clear()
        return pages

    # -- EEPROM and lock bits --------------------------------------------------------------
    def write_eeprom(self, address: int, value: int) -> None:
        self.eeprom[address % EEPROM_SIZE] = value  # EEAR has 12 bits: the address wraps

    def read_eeprom(self, address: int) -> int:
        return self.eeprom[address % EEPROM_SIZE]

    def program_lock_bits(self, bits: int) -> None:
        """boot_lock_bits_set: program (clear) the boot lock bits set in `bits`; SPM can never
        set a lock bit again, only a programmer's chip erase does."""
        self.lock &= ~(bits & BLB_MASK) & 0xFF
