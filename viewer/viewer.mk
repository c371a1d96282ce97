# viewer/viewer.mk — the OpenGL viewer, included by the Makefile.
#
#   build/viewer            one binary, three context backends (--backend glfw|egl|osmesa)
#   build/glad/             the GL 3.3 core loader, generated here by Debian's python3-glad
#   build/viewer-obj/       its objects (build/viewer itself is the executable)
#
# GLFW, stb (stb_truetype, for the labels' DejaVu Sans) and cJSON (reading the stats JSON) are linked; EGL and
# OSMesa are dlopen()ed at run time by viewer/backend.c, so libGL and libOSMesa never meet in one link line.

VIEWER_PACKAGES := libglfw3-dev libegl-dev libegl1-mesa-dev libgl-dev libosmesa6-dev python3-glad \
                   libstb-dev fonts-dejavu-core libcjson-dev

VIEWER_SRC  := $(wildcard viewer/*.c)
VIEWER_OBJ  := $(VIEWER_SRC:viewer/%.c=$(BUILD)/viewer-obj/%.o)
GLAD_DIR    := $(BUILD)/glad
GLAD_HEADER := $(GLAD_DIR)/include/glad/gl.h

.PHONY: viewer
all: $(BUILD)/viewer
viewer: $(BUILD)/viewer

# --reproducible: no timestamp in the output, and the Khronos XML comes from
# the package (no network).  No extensions: the viewer uses core 3.3 only.
$(GLAD_HEADER):
	@mkdir -p $(GLAD_DIR)
	glad --quiet --reproducible --api gl:core=3.3 --extensions "" --out-path $(GLAD_DIR) c
	@test -f $(GLAD_DIR)/src/gl.c
$(GLAD_DIR)/src/gl.c: $(GLAD_HEADER) ; @true

$(BUILD)/viewer-obj/glad.o: $(GLAD_DIR)/src/gl.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -I$(GLAD_DIR)/include -c $< -o $@

$(BUILD)/viewer-obj/%.o: viewer/%.c $(GLAD_HEADER)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -Icommon -I$(GLAD_DIR)/include -c $< -o $@

$(BUILD)/viewer: $(VIEWER_OBJ) $(BUILD)/viewer-obj/glad.o $(COMMON_OBJ)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $^ -o $@ $(LDFLAGS) -lglfw -lstb -lcjson -ldl $(LDLIBS)
