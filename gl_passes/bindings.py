"""Units of a family of shaders, handed out in one place (pyrender-style): a unit
table names the images, storage buffers and textures its shaders use, gives
each the next free unit of its kind, and is both the source of the shaders'
`binding = UNIT_<name>` #defines and the only way the Python side binds them —
so no pass writes a literal unit number on either side. (moderngl 5.13 cannot
set an image uniform's unit on a compute shader, so units are fixed at compile
time by these #defines.)

Images are the scarce kind: GL 4.3 guarantees 8 image units and NVIDIA's driver
gives no more (a `binding = 8` image fails to compile there), so a family with more
write targets lists them in groups, one per set of shaders that bind them
together; each group counts from unit 0, and every pass binds its images before it
dispatches."""

from __future__ import annotations

from dataclasses import dataclass, field

import moderngl

#: GL_MAX_IMAGE_UNITS guaranteed by OpenGL 4.3, and what NVIDIA's driver reports.
MAX_IMAGE_UNITS = 8


@dataclass(frozen=True)
class Units:
    """Names of the image uniforms, storage blocks and sampler uniforms of a
    family of shaders, in unit order (units count from 0 per kind). `images` is a
    tuple of names, or of groups (tuples of names) never bound by one pass, each
    group counting from 0 and holding at most MAX_IMAGE_UNITS names."""

    images: tuple[str, ...] | tuple[tuple[str, ...], ...] = ()
    storage: tuple[str, ...] = ()
    textures: tuple[str, ...] = ()
    _image_units: dict[str, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        groups = [self.images] if all(isinstance(n, str) for n in self.images) else list(self.images)
        units: dict[str, int] = {}
        for group in groups:
            if isinstance(group, str) or len(group) > MAX_IMAGE_UNITS:
                raise ValueError(f"image group {group!r}: groups are tuples of at most {MAX_IMAGE_UNITS} names")
            for unit, name in enumerate(group):
                if name in units:
                    raise ValueError(f"image {name!r} listed twice")
                units[name] = unit
        object.__setattr__(self, "_image_units", units)

    @property
    def image_units(self) -> dict[str, int]:
        """Image name → unit."""
        return dict(self._image_units)

    def defines(self) -> dict[str, str]:
        """#defines UNIT_<name> → unit for every name (compile the shaders with them)."""
        out = {f"UNIT_{n}": str(k) for n, k in self._image_units.items()}
        for names in (self.storage, self.textures):
            out.update({f"UNIT_{n}": str(k) for k, n in enumerate(names)})
        return out

    def bind_image(self, name: str, tex: moderngl.Texture | moderngl.TextureArray, read: bool = True,
              write: bool = False) -> None:
        """Bind `tex` to the image unit of `name` (read and/or write access)."""
        tex.bind_to_image(self._image_units[name], read=read, write=write)

    def bind_storage(self, name: str, buf: moderngl.Buffer) -> None:
        """Bind `buf` to the storage-buffer binding of block `name`."""
        buf.bind_to_storage_buffer(self.storage.index(name))

    def bind_texture(self, name: str, tex: moderngl.Texture | moderngl.TextureArray) -> None:
        """Bind `tex` to the texture unit of sampler `name`."""
        tex.use(location=self.textures.index(name))
