"""Units of a family of shaders, handed out in one place (pyrender-style): a unit
table names the images, storage buffers and textures its shaders use, gives
each the next free unit of its kind, and is both the source of the shaders'
`binding = UNIT_<name>` #defines and the only way the Python side binds them —
so no pass writes a literal unit number on either side. (moderngl 5.13 cannot
set an image uniform's unit on a compute shader, so units are fixed at compile
time by these #defines.)"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl


@dataclass(frozen=True)
class Units:
    """Names of the image uniforms, storage blocks and sampler uniforms of a
    family of shaders, in unit order (units count from 0 per kind)."""

    images: tuple[str, ...] = ()
    storage: tuple[str, ...] = ()
    textures: tuple[str, ...] = ()

    def defines(self) -> dict[str, str]:
        """#defines UNIT_<name> → unit for every name (compile the shaders with them)."""
        out: dict[str, str] = {}
        for names in (self.images, self.storage, self.textures):
            out.update({f"UNIT_{n}": str(k) for k, n in enumerate(names)})
        return out

    def bind_image(self, name: str, tex: moderngl.Texture | moderngl.TextureArray, read: bool = True,
              write: bool = False) -> None:
        """Bind `tex` to the image unit of `name` (read and/or write access)."""
        tex.bind_to_image(self.images.index(name), read=read, write=write)

    def bind_storage(self, name: str, buf: moderngl.Buffer) -> None:
        """Bind `buf` to the storage-buffer binding of block `name`."""
        buf.bind_to_storage_buffer(self.storage.index(name))

    def bind_texture(self, name: str, tex: moderngl.Texture | moderngl.TextureArray) -> None:
        """Bind `tex` to the texture unit of sampler `name`."""
        tex.use(location=self.textures.index(name))
