# libraries.mk: the libraries/ support of Runtime v4's program build, for runtimes whose
# scripts/Makefile.strucpp predates it (v4.1.4 and its forks): each library folder a program
# carries in core/generated/libraries/<name>/ (library.properties + src/) is compiled and
# linked into the program .so, and the program is built with -fno-gnu-unique (so that the
# runtime's dlclose on Stop really unmaps it). Read after the runtime's own Makefile, in the
# runtime's root, where compile.sh runs make:
#
#   make -f scripts/Makefile.strucpp -f <this file>
#
# What it adds, the same as the runtimes with libraries/ support do:
# - every libraries/*/src on the include path of the program's TUs, of runtime_v4_entry.cpp
#   (generated.hpp includes a library's headers) and of every library source;
# - each library's `defines=` (library.properties, comma-separated) on its own sources;
# - libraries/*/src/*.c compiled as C (-O1 -fPIC), *.cpp with the program's C++ flags;
# - the objects linked into build/new_libplc.so (an extra prerequisite of the same target: the
#   runtime's link rule links $^).
LIB_ROOT     := $(GENERATED_DIR)/libraries
LIB_NAMES    := $(notdir $(patsubst %/,%,$(dir $(wildcard $(LIB_ROOT)/*/library.properties))))
LIB_INC      := $(foreach n,$(LIB_NAMES),-I $(LIB_ROOT)/$(n)/src)
LIB_CFLAGS   := -O1 -pipe -fPIC -Wall -MMD -MP -Wno-unknown-pragmas -Wno-deprecated-declarations
LIB_OBJ_DIR  := $(BUILD_DIR)/libraries

GENERATED_CXXFLAGS += -fno-gnu-unique $(LIB_INC)
CXXFLAGS           += -fno-gnu-unique $(LIB_INC)

lib_defines = $(addprefix -D,$(subst $(COMMA), ,$(shell sed -n 's/^defines=//p' $(LIB_ROOT)/$(1)/library.properties)))
COMMA := ,

define LIB_RULES
LIB_$(1)_C   := $$(wildcard $(LIB_ROOT)/$(1)/src/*.c)
LIB_$(1)_CXX := $$(wildcard $(LIB_ROOT)/$(1)/src/*.cpp)
LIB_$(1)_OBJ := $$(patsubst $(LIB_ROOT)/$(1)/src/%.c,$(LIB_OBJ_DIR)/$(1)/%.o,$$(LIB_$(1)_C)) \
                $$(patsubst $(LIB_ROOT)/$(1)/src/%.cpp,$(LIB_OBJ_DIR)/$(1)/%.cpp.o,$$(LIB_$(1)_CXX))
LIB_OBJS += $$(LIB_$(1)_OBJ)
$(LIB_OBJ_DIR)/$(1)/%.o: $(LIB_ROOT)/$(1)/src/%.c
	@mkdir -p $$(@D)
	$$(CC) $(LIB_CFLAGS) $(LIB_INC) $(call lib_defines,$(1)) -c $$< -o $$@
$(LIB_OBJ_DIR)/$(1)/%.cpp.o: $(LIB_ROOT)/$(1)/src/%.cpp
	@mkdir -p $$(@D)
	$$(CXX) $(CXXFLAGS) $(LIB_INC) $(call lib_defines,$(1)) -c $$< -o $$@
endef
LIB_OBJS :=
$(foreach n,$(LIB_NAMES),$(eval $(call LIB_RULES,$(n))))

$(LIBPLC): $(LIB_OBJS)
-include $(LIB_OBJS:.o=.d)
